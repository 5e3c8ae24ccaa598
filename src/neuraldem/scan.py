"""`neuraldem scan SCENE name=LO:HI:N name=LO:HI:N name=VALUE`: a design chart over two parameters in seconds.

    neuraldem scan hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1
    neuraldem scan hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1 verify=4   # + 4 points run with the solver

Two parameters span a grid, the others are fixed; the scene's shipped GP answers every point (`Scene.scan`;
a scene with one parameter has no chart: `neuraldem predict` at the values you want is its scan).
"""

from __future__ import annotations

import sys

from neuraldem import pretrained
from neuraldem.cli import report_user_errors
from neuraldem.predict import peek, what_if, what_if_parser


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    found = what_if("scan", argv, "scan")
    if isinstance(found, str):
        print(found)
        return 0
    scene, module = found
    name = peek(argv[1:], "model") or pretrained.default_for(scene.kind)
    inputs = list(pretrained.load(name, scene.kind).meta["inputs"])
    p = what_if_parser("scan", scene, module, inputs, "LO:HI:N|VALUE")
    module.add_options(p)
    args = p.parse_args(argv[1:])
    items = {n: getattr(args, n) for n in inputs if getattr(args, n) is not None}
    return int(module.scan(items, name, args.out, args))


if __name__ == "__main__":
    sys.exit(main())
