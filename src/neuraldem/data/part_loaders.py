"""A LightningDataModule base whose train/val/test loaders come from `self.datasets[part]`."""

from __future__ import annotations

import lightning as L
from torch.utils.data import DataLoader


class PartLoaders(L.LightningDataModule):
    """Subclasses set `datasets` (part -> Dataset), `batch_size` and `num_workers` in setup. A part without
    samples gives no loader (an empty list: Lightning skips it); training drops a last partial batch only when
    there is a whole one. `loader_class` is the DataLoader to use (torch_geometric's for graph samples)."""

    loader_class: type = DataLoader
    datasets: dict
    batch_size: int
    num_workers: int

    def _loader(self, part: str, shuffle: bool) -> DataLoader | list:
        if not len(self.datasets[part]):
            return []
        return self.loader_class(self.datasets[part], batch_size=self.batch_size, shuffle=shuffle,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0,
                          drop_last=shuffle and len(self.datasets[part]) >= self.batch_size)

    def train_dataloader(self) -> DataLoader | list:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader | list:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader | list:
        return self._loader("test", shuffle=False)
