"""`python -m neuraldem.bench NAME [args]`: run one benchmark by name; without a name, list them."""

from __future__ import annotations

import importlib
import sys

from neuraldem.errors import NeuraldemError

# name -> (module with `main(argv) -> int`, what it measures); modules are imported only when run
BENCHMARKS = {
    "model_step": ("neuraldem.bench.model_step",
                   "forward+backward time per training step of model configs, 1 vs 2 torch threads"),
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m neuraldem.bench NAME [args]   (NAME --help for its options)\n\nbenchmarks:")
        for name, (_, description) in BENCHMARKS.items():
            print(f"  {name:<14} {description}")
        return 0
    name, args = argv[0], argv[1:]
    if name not in BENCHMARKS:
        print(f"error: unknown benchmark {name!r}; choose one of {sorted(BENCHMARKS)}", file=sys.stderr)
        return 2
    try:
        return importlib.import_module(BENCHMARKS[name][0]).main(args)
    except NeuraldemError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
