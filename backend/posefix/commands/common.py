"""What several command areas share."""

from __future__ import annotations

import os
import sys
import warnings
from contextlib import contextmanager
from typing import Iterator

import click

EXIT_BAD_INPUT = 1
# Every command shows its options' defaults in --help.
CONTEXT = {"show_default": True}


def single_threaded_blas() -> None:
    """One BLAS thread unless the user chose otherwise (before numpy is first imported).

    The engine's linear algebra is 6x6 blocks, thin (n,3) products and a banded Cholesky:
    BLAS threads only spin against each other (and against the CSV parser) on them.
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        os.environ.setdefault("OMP_NUM_THREADS", "1")


class CommandError(Exception):
    """A user-facing failure: printed as one line, exit status 1."""


def fail(message: str) -> None:
    one_line = " ".join(str(message).split())  # messages from libraries may span lines
    click.echo(f"error: {one_line}", err=True)
    raise click.exceptions.Exit(EXIT_BAD_INPUT)


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn every expected failure into one line on stderr and a non-zero exit.

    Warnings (e.g. an orientation derived from the track) are printed as one line each.
    """
    from posefix.io.errors import RunFormatError

    def show_warning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"warning: {message}", err=True)

    old = warnings.showwarning
    warnings.showwarning = show_warning
    try:
        yield
    except click.exceptions.Exit:
        raise
    except (RunFormatError, CommandError) as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        fail("interrupted; nothing written")
    except (ValueError, OSError) as exc:  # engine refusals, config errors, unreadable files
        if os.environ.get("POSEFIX_DEBUG"):
            raise
        fail(str(exc) if type(exc) is ValueError else f"{type(exc).__name__}: {exc}")
    finally:
        warnings.showwarning = old
