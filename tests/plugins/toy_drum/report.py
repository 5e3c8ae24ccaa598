"""`neuraldem report drum-table dataset=DIR`: the toy drum's runs, one line each."""

from __future__ import annotations

import sys
from pathlib import Path

from neuraldem.cli import command_parser, report_user_errors
from neuraldem.data.manifest import Manifest


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = command_parser("toy_drum.report", __doc__)
    p.add_argument("--dataset", type=Path, required=True)
    args = p.parse_args(argv)
    for r in Manifest.load(args.dataset).usable():
        print(f"{r.sim_id} speed={r.params['speed']:.2f} repose={r.metrics['dynamic_repose_deg']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
