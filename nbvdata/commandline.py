"""What the two command lines (``nbvdata``, ``nbvtrain``) share: a parser whose usage errors are
one line, checked argparse types for counts, lengths and shares, and a quiet exit when the
reader of stdout goes away (``nbvdata inspect DIR | head -1``).

Every option that takes a number uses one of the types here, so a bad value (``--scans 0``,
``--k nan``, ``--epochs abc``) stops the command before it starts, in one line with exit status 2.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import select
import signal
import sys
import textwrap
from dataclasses import dataclass
from typing import Callable

from nbvdata.core.errors import UserError

CLOSED_PIPE_STATUS = 128 + signal.SIGPIPE
"""141: what a shell reports for a tool that SIGPIPE stopped, as ``yes | head -1`` does for ``yes``."""


class WholeWords(argparse.HelpFormatter):
    """Help text wrapped at spaces only: a name with hyphens (``--random-starts``, ``proximity-count``)
    stays whole on one line, so it can be found and pasted."""

    def _split_lines(self, text, width):
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text, width, indent):
        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent, subsequent_indent=indent,
                             break_on_hyphens=False)


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line naming ``--help``, exit status 2; its
    subcommands' parsers are Parsers too; help wraps at spaces only (``WholeWords``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", WholeWords)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} ({self.prog} --help lists the options)\n")


@dataclass(frozen=True)
class Integer:
    """argparse type: a whole number >= ``minimum``."""

    minimum: int

    def __call__(self, text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < self.minimum:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {self.minimum}, not {text!r}")
        return value


@dataclass(frozen=True)
class Number:
    """argparse type: a finite number in [``low``, ``high``] (``low`` excluded when ``low_open``)."""

    low: float
    high: float = math.inf
    low_open: bool = False

    def __call__(self, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = self.low < value if self.low_open else self.low <= value
        if not (math.isfinite(value) and inside and value <= self.high):
            raise argparse.ArgumentTypeError(f"must be {self.describe()}, not {text!r}")
        return value

    def describe(self) -> str:
        """"a positive finite number", "a number in [0, 1]", ..."""
        if math.isfinite(self.high):
            return f"a number in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"
        if self.low == 0:
            return "a positive finite number" if self.low_open else "a finite number >= 0"
        return f"a finite number {'>' if self.low_open else '>='} {self.low:g}"


positive_int = Integer(1)
"""A count of things that needs at least one: scans, epochs, rows."""
non_negative_int = Integer(0)
"""A seed, an index, or a count where 0 means none (or "one per core")."""
positive_float = Number(0.0, low_open=True)
"""A length, scale or rate: finite and > 0."""
non_negative_float = Number(0.0)
"""A size where 0 is allowed: finite and >= 0."""
fraction = Number(0.0, 1.0)
"""A share or probability in [0, 1]."""


def exit_quietly_when_stdout_closes(main: Callable[[list[str] | None], int]) -> Callable[[list[str] | None], int]:
    """Wrap a command line's ``main(argv) -> status``: when the reader of stdout has gone
    (``| head -1`` read its line), stop with status 141 as a Unix tool stopped by SIGPIPE does,
    printing nothing, instead of a BrokenPipeError traceback.

    Python ignores SIGPIPE, so a write to a closed pipe raises BrokenPipeError: from a print, or
    from the flush of buffered output, which is done here (not at interpreter exit, where it
    could only be reported as "Exception ignored"). stdout is then pointed at /dev/null, so the
    interpreter's last flush of what is left cannot fail (the Python docs' recipe, "Note on
    SIGPIPE"). A BrokenPipeError while stdout's reader is still there (a worker's pipe) is an error
    like any other and propagates."""

    @functools.wraps(main)
    def run(argv: list[str] | None = None) -> int:
        try:
            try:
                status = main(argv)
            except SystemExit:  # --help, --version, a usage error: flush what they wrote
                sys.stdout.flush()
                raise
            sys.stdout.flush()
            return status
        except BrokenPipeError:
            if not _stdout_reader_gone():
                raise
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return CLOSED_PIPE_STATUS

    return run


def _stdout_reader_gone() -> bool:
    """Whether stdout is a pipe or socket with no reader left (poll reports an error or hang-up on
    it); True where this cannot be asked (no poll, stdout without a file descriptor)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return True


def run_command(program: str, args: argparse.Namespace) -> int:
    """Run the parsed subcommand ``args.func(args)`` as both command lines do: a ``UserError`` is
    its message in one line and exit status 2, Ctrl-C exit status 130."""
    try:
        return args.func(args)
    except UserError as error:
        print(f"{program} {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{program} {args.command}: interrupted", file=sys.stderr)
        return 130
