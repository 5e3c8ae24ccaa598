"""`neuraldem serve`: the interactive explorer of the shipped models in your browser.

    neuraldem serve                        # http://127.0.0.1:5006/hopper and /bed
    neuraldem serve port=5010 show=true    # another port, and open the browser
    neuraldem serve model=hopper_small dataset=~/data/hopper_small
    neuraldem serve model=$HOME/my-models/my_hopper     # a model you released (neuraldem release ... out=DIR)

Hopper page: sliders for the cone angle and the two frictions (their trained ranges; type a value beside a
slider to go beyond: values past what LIGGGHTS can run are clamped with a note, values past the trained range
get the extrapolation warning of `neuraldem predict`), a time player, the particles in 3D coloured by initial
layer or residence time, the discharge curve, and the numbers with 95 % intervals: the GP's at once, the field
model's when its whole discharge is computed (a few seconds), and a stored LIGGGHTS run's when one is within
near= of the point.

Bed page: the inlet-velocity slider (same clamping and warnings), the GP's three numbers (mean bed height,
bubble fraction, Lacey after 1 s) with 95 % intervals at once, animated solid-fraction and mixing maps and the
bed-height / bubble-fraction / Lacey curves of the nearest rollout already computed (a lattice of 9 velocities
rolls out in the background at start; the rollout at the slider's velocity replaces it once the slider rests),
and the held-out errors of both models beside CFD-DEM's own spread. `page=hopper` serves one page only.
Needs the `serve` extra: pip install -e '.[serve]'.
"""

from __future__ import annotations

import sys
from pathlib import Path

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.errors import ConfigError
from neuraldem.serve.inputs import NEAR
from neuraldem.serve.ports import check_port

DEFAULT_PORT = 5006


def require_web_packages() -> None:
    missing = []
    for name in ("panel", "plotly"):
        try:
            __import__(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise ConfigError(f"neuraldem serve needs {' and '.join(missing)}",
                          "install the serve extra: pip install -e '.[serve]' (scripts/setup.sh does)")


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.serve", __doc__)
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free one)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine)")
    p.add_argument("--model", default=None,
                   help="a model's name or released folder to show on its scene's page (default: each scene's first "
                        "model found, yours before the shipped one)")
    p.add_argument("--dataset", type=Path, default=None,
                   help="stored LIGGGHTS runs to overlay (default: the model's own dataset in the data dir)")
    p.add_argument("--near", type=float, default=NEAR,
                   help=f"a stored run is shown when every parameter is within this share of its trained range "
                        f"(default {NEAR})")
    p.add_argument("--page", action="append", default=None, help="serve only this page (repeatable)")
    p.add_argument("--show", action="store_true", help="open the browser")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    if not 0 <= args.near <= 1:
        raise ConfigError(f"near={args.near} is invalid", "give a share of the trained range in 0 .. 1, e.g. 0.05")
    port = check_port(args.host, args.port)  # before the slow loading: a port in use is told at once
    require_web_packages()
    from neuraldem.scenes import registry
    from neuraldem.serve.app import prepare_pages, serve

    routes = {s.route: (s.kind, s.page) for s in registry().values() if s.page}
    pages, notes = prepare_pages(routes, args.model, args.dataset, args.near, args.page)
    for note in notes:
        print(f"neuraldem serve: {note}", file=sys.stderr)
    for page in pages:
        print(f"neuraldem serve: {page.route} page at http://{args.host}:{port}/{page.route}", flush=True)
    try:
        serve(pages, notes, args.host, port, args.show)
    except OSError as err:  # taken between the check and the start
        raise ConfigError(f"cannot listen on {args.host}:{port} ({err.strerror})",
                          f"try port={check_port(args.host, 0)}") from None
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
