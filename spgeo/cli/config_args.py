"""``--config FILE`` / ``--set FIELD=VALUE`` / ``--dump-config [FILE]`` arguments of
the ``spgeo`` commands; the parsing, the overrides and the TOML itself are the
library's :mod:`spgeo.configs`."""
from __future__ import annotations

import argparse
import sys
from typing import Any, Callable

from ..configs import config_to_toml


class _DumpConfig(argparse.Action):
    """``--dump-config [FILE]``: write the defaults as TOML (to FILE, atomically, or
    to stdout) and exit 0, as ``--help`` does: no other argument is needed."""

    def __init__(self, option_strings, dest, defaults: Callable[[], Any], command: str,
                 **kwargs) -> None:
        super().__init__(option_strings, dest, nargs="?", const="-", default=None, **kwargs)
        self.defaults = defaults
        self.command = command

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        config = self.defaults()
        text = config_to_toml(config, title=(
            f"{type(config).__name__} defaults of `{self.command}`; edit, then read with "
            f"`{self.command} --config FILE`\nor, in Python, "
            f"spgeo.configs.resolve_config({type(config).__name__}(), FILE).\nAbove each "
            "field, what it means (the first clause of its class's docstring entry)."))
        if values == "-":
            sys.stdout.write(text)
        else:
            from ..io.outputs import write_bytes_atomic
            from ..validation import InputError

            try:
                write_bytes_atomic(values, text.encode("utf-8"), "--dump-config")
            except (InputError, OSError) as exc:
                parser.exit(2, f"{parser.prog}: error: {exc}\n")
            print(f"wrote the {type(config).__name__} defaults to {values}")
        parser.exit(0)


def add_config_arguments(parser: argparse.ArgumentParser, what: str,
                         defaults: Callable[[], Any]) -> None:
    """``--config FILE``, ``--set FIELD=VALUE ...`` (dest ``config_file`` /
    ``set``) and ``--dump-config [FILE]``; ``what`` names the config class in the
    help, ``defaults`` builds the default config that ``--dump-config`` writes."""
    parser.add_argument("--config", dest="config_file", default=None, metavar="FILE",
                        help=f"{what} fields from a TOML (or YAML) file")
    parser.add_argument("--set", dest="set", nargs="+", action="extend", default=[],
                        metavar="FIELD=VALUE",
                        help=f"{what} field overrides, Python literals, true / false or "
                             f"plain strings (nested: a.b=1); override --config")
    parser.add_argument("--dump-config", action=_DumpConfig, metavar="FILE",
                        defaults=defaults, command=parser.prog,
                        help=f"write the {what} defaults as TOML to FILE (default: stdout), "
                             f"a template for --config, and exit")
