"""``rollergear figures``: the paper's sensitivity study (Figs. 6-11) as PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..base.atomic import together
from ..sources.paths import Output, check_outputs
from .args import add_params_option, config_from_args

EXAMPLE = "rollergear figures --out figures/"


# ---------------------------------------------------------------------------------- figures / map
def cmd_figures(args: argparse.Namespace) -> int:
    from ..calibration.figures import write_figures

    check_outputs([args.params], [Output("--out", args.out, "folder", ("fig*.png", "figures.csv"))])
    with together():  # the six pictures and their table are put in place together, or none
        paths = write_figures(config_from_args(args), Path(args.out))
    for p in paths:
        print(p)
    return 0


def register(sub) -> None:
    p = add_params_option(sub.add_parser("figures", help="the paper's sensitivity study (Figs. 6-11) as PNG"))
    p.add_argument("--out", required=True, metavar="DIR", help="folder for fig06.png … fig11.png and figures.csv")
    p.set_defaults(func=cmd_figures)
