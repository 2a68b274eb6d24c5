"""``rollergear``: the command line -- the table of verbs and the dispatch.

One module of this wing per verb (as ``ros2bag/verb/*.py``): each holds its ``EXAMPLE``, its
``register(sub)`` (its parser, with ``func`` the command) and the command; options more than one verb
takes live in :mod:`.args`; no verb module imports another, and a verb that needs rclpy imports it when
it runs.  Every subcommand loads its parameters through :func:`core.params.load_config`; errors in user
input are one line ``rollergear: error: …`` with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from ..base.errors import RollergearError
from ..base.interface import package_version
from ..ros.nodehelp import contract_line
from . import calibrate, export, figures, fleet, import_, info, model, play, predict, replay, simulate, watch
from . import map as map_verb

#: the verbs in the order ``rollergear --help`` lists them: verb -> its module
VERBS = {"model": model, "figures": figures, "map": map_verb, "info": info, "simulate": simulate, "replay": replay,
         "import": import_, "calibrate": calibrate, "fleet": fleet, "play": play, "watch": watch, "export": export,
         "predict": predict}
#: one example per verb, shown at the end of its --help
EXAMPLES = {name: verb.EXAMPLE for name, verb in VERBS.items()}
CONTRACT = contract_line()


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rollergear", description="Roller gearing gearbox loss model, "
                                 "replay, calibration and ROS 2 tools.", epilog=CONTRACT)
    ap.add_argument("--version", action="version", version=f"rollergear {package_version()}")
    sub = ap.add_subparsers(dest="command", required=True)
    for verb in VERBS.values():
        verb.register(sub)
    for name, parser in sub.choices.items():
        parser.formatter_class = argparse.RawDescriptionHelpFormatter
        parser.epilog = "\n".join(filter(None, (parser.epilog, f"example:\n  {EXAMPLES[name]}", CONTRACT)))
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if sys.stdout is None:  # started with its standard output closed (>&-): nothing it says would be seen
        if sys.stderr is not None:
            print("rollergear: error: standard output is closed", file=sys.stderr)
        return 2
    stdout, sys.stdout = sys.stdout, _NamedStdout(sys.stdout)
    try:
        return _run(args)
    finally:
        sys.stdout = stdout


def _run(args: argparse.Namespace) -> int:
    """The command, its errors as one line and an exit status."""
    try:
        status = int(args.func(args) or 0)
        sys.stdout.flush()  # what is still buffered: a full device is said here, not at exit
        return status
    except RollergearError as exc:
        print(f"rollergear: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rollergear: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:
        if exc.filename == STDOUT:
            _discard_stdout()
        elif exc.filename is None:  # not about a file: a defect, shown as one
            raise
        # the file system refused (disk full, permissions changed during the run): one line
        print(f"rollergear: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2


STDOUT = "standard output"  #: the file name an error writing standard output carries


class _NamedStdout:
    """Standard output whose write errors (a full device, a closed descriptor) name it: one error
    line, as for any file, instead of a traceback."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def _discard_stdout() -> None:
    """After standard output failed: what it still buffers goes to /dev/null, so that the
    interpreter's exit does not fail on it again (and print a traceback of its own)."""
    try:
        stream = sys.stdout._stream if isinstance(sys.stdout, _NamedStdout) else sys.stdout
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":  # run as the package's module so exception classes are shared
    from rollergear_ros.cli.main import main as _main

    sys.exit(_main())
