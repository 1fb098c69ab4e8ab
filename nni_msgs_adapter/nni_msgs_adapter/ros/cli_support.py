"""Command-line plumbing shared by nni-simulate, nni-demo and nni-replay.

Bad input gets one line on stderr naming the problem and a non-zero exit, never
a traceback; output files appear whole or not at all. No ROS import.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

#: Exit status for bad input (as argparse uses).
EXIT_USAGE = 2


class CliError(Exception):
    """A user-facing error: printed as one line, exit status ``EXIT_USAGE``."""


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line (``prog: error: ...``), exit 2."""

    def error(self, message: str) -> None:  # noqa: D102 - argparse API
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def battery_limit(text: str) -> float:
    """argparse type for a battery limit b in pu: a number >= 0 or ``inf``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"battery limit must be a number >= 0 or 'inf', got {text!r}") from None
    if math.isnan(value) or value < 0:
        raise argparse.ArgumentTypeError(f"battery limit must be a number >= 0 or 'inf', got {text!r}")
    return value


def _finite(text: str, condition, expected: str) -> float:
    """Parse a finite number meeting ``condition``; ArgumentTypeError saying what was expected."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and condition(value)):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type for a finite number > 0."""
    return _finite(text, lambda value: value > 0, "a finite number > 0")


def positive_int(text: str) -> int:
    """argparse type for an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """argparse type for any finite number."""
    return _finite(text, lambda value: True, "a finite number")


def float_within(low: float, high: float, unit: str):
    """argparse type for a number within [low, high] (``unit`` names it in the error)."""

    def parse(text: str) -> float:
        return _finite(text, lambda value: low <= value <= high, f"{low:g}..{high:g} {unit}")

    return parse


def writable_output(text: str) -> Path:
    """argparse type for an output file whose folder exists and takes new files.

    Probed by creating (and removing) a temporary file there, as
    :func:`atomic_output` will: permission bits alone say yes to root on
    read-only mounts and pseudo file systems such as /proc.
    """
    path = Path(text)
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, expected a file path")
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(f"output folder {folder} does not exist")
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".probe")
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"output folder {folder} is not writable ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)
    return path


@contextmanager
def atomic_output(path: Path, mode: str = "w"):
    """Open a temporary file beside ``path``; rename it over ``path`` only on success."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, mode) as handle:
            yield handle
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, content) -> None:
    """``content`` as indented JSON ending in a newline, written whole or not at all (:func:`atomic_output`)."""
    with atomic_output(path) as handle:
        json.dump(content, handle, indent=2)
        handle.write("\n")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def given_options(argv) -> list[str]:
    """The ``--option`` words of a command line (``--name=value`` as ``--name``)."""
    return [word.split("=", 1)[0] for word in argv if word.startswith("--")]


def run_cli(main_body, prog: str) -> int:
    """Run ``main_body()``; turn expected failures into one line and an exit status.

    CliError, ValueError (invalid parameters) and OSError (files) become
    ``prog: error: message``; Ctrl-C exits 130 quietly.
    """
    try:
        return main_body() or 0
    except (CliError, ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE if isinstance(exc, (CliError, ValueError)) else 1
    except KeyboardInterrupt:
        return 130
