"""``--config FILE`` / ``--set FIELD=VALUE`` arguments of the ``spgeo`` commands;
the parsing and the overrides themselves are the library's :mod:`spgeo.configs`."""
from __future__ import annotations

import argparse


def add_config_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--config FILE`` and ``--set FIELD=VALUE ...`` (dest ``config_file`` /
    ``set``); ``what`` names the config class in the help."""
    parser.add_argument("--config", dest="config_file", default=None, metavar="FILE",
                        help=f"{what} fields from a TOML (or YAML) file")
    parser.add_argument("--set", dest="set", nargs="+", action="extend", default=[],
                        metavar="FIELD=VALUE",
                        help=f"{what} field overrides, Python literals or plain strings "
                             f"(nested: a.b=1); override --config")
