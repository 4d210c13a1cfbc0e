"""The skeleton every a3d command shares: one parser style and one error -> exit-code mapping.

Exit codes, the same for every a3d command:

- 0 (``EXIT_OK``): everything done;
- 1 (``EXIT_FAILED``): the command ran but some inputs failed (each named on stderr), or a check
  of its result failed (a3d-export's verification);
- 2 (``EXIT_USAGE``): a usage error or an unusable input, found before any work: argparse's own
  errors, and the ``InputError`` / ``ModelError`` (plus the errors a command lists) that reach
  ``main``, printed as one line ``PROG: error: message``; a missing optional extra (torch for the
  training commands), one line ``PROG: needs the 'train' extra: pip install 'a3d[train]' (torch is
  missing)``, checked once the flags are parsed, so ``--help`` and ``--version`` work without it;
- 130 (``EXIT_INTERRUPTED``): Ctrl-C.

Help texts are plain text (no reST markup: argparse prints them as they are) and every option
shows its default, so ``--help`` is the reference. Torch-free: the training commands import it
from the runtime, never the reverse.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import PackageNotFoundError, version

from a3d.runtime.errors import InputError, ModelError
from a3d.runtime.extras import MissingExtra, Needs
from a3d.runtime.sources.wording import command_line

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def a3d_version() -> str:
    """The installed distribution's version ("unknown" when run from a tree that is not installed)."""
    try:
        return version("a3d")
    except PackageNotFoundError:
        return "unknown"


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks and appends "(default: X)" to every option that has a
    default and does not state one already; options without one (None, False, []) say nothing."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "default" in text
            or default is None
            or default is False
            or default == []
            or default is argparse.SUPPRESS
            or not action.option_strings
        ):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else "%(default)s"
        return f"{text} (default: {shown})"


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser that checks the command's extra once the flags parse (after --help)."""

    def __init__(self, needs: Needs | None, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.needs = needs

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        parsed = super().parse_known_args(args, namespace)
        if self.needs is not None:
            self.needs.check()
        return parsed


def build_parser(
    prog: str, description: str, epilog: str | None = None, needs: Needs | None = None
) -> argparse.ArgumentParser:
    """The parser of one a3d command: plain-text help with defaults shown, and ``--version``;
    with ``needs``, parsing raises MissingExtra when the command's extra is not installed."""
    parser = _Parser(needs, prog=prog, description=description, epilog=epilog, formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"a3d {a3d_version()}")
    return parser


def command(
    prog: str, errors: tuple[type[BaseException], ...] = ()
) -> Callable[[Callable[..., int]], Callable[..., int]]:
    """Decorate a command's ``main(argv) -> int`` with the shared error -> exit-code mapping.

    ``InputError``, ``ModelError`` and ``errors`` become one line ``PROG: error: message`` and exit
    code 2; a missing extra (MissingExtra, or an optional module that a lazy import did not find)
    one line ``PROG: needs the 'EXTRA' extra: ...`` and exit code 2; Ctrl-C exits 130 with one
    line. ``main`` itself returns 0 or 1 (some inputs failed).
    """
    usage_errors = (InputError, ModelError, *errors)

    def wrap(main: Callable[..., int]) -> Callable[..., int]:
        @functools.wraps(main)
        def run(argv: list[str] | None = None, **options: object) -> int:
            try:
                with command_line():  # errors name the flags, not the Python keywords
                    return main(argv, **options)
            except MissingExtra as e:
                print(f"{prog}: {e}", file=sys.stderr)
                return EXIT_USAGE
            except ModuleNotFoundError as e:
                missing = MissingExtra.of(e)
                if missing is None:
                    raise
                print(f"{prog}: {missing}", file=sys.stderr)
                return EXIT_USAGE
            except usage_errors as e:
                print(f"{prog}: error: {e}", file=sys.stderr)
                return EXIT_USAGE
            except KeyboardInterrupt as e:  # its message, if any, says what was kept
                print(f"\n{prog}: interrupted" + (f"; {e}" if str(e) else ""), file=sys.stderr)
                return EXIT_INTERRUPTED

        return run

    return wrap
