"""How every user-facing command ends: a documented exit code, one line, never a traceback.

Exit codes (the same for ``fleetgate``, ``fleetgate-robot``, ``python -m tracecheck`` and
every ``bench/`` script):

=====  ====================================================================================
0      success
1      a check the command ran failed (a trace with errors, a non-conforming target, a
       benchmark whose goal was missed)
2      bad input or an environment error (one line on stderr: an unreadable input, an
       output that cannot be written such as ``/dev/full``, a file where a folder is
       expected, a port in use, nothing listening)
3      no solution within the time limit (planning commands)
130    interrupted: Ctrl-C (SIGINT); long-running commands stop cleanly first
141    the reader of standard output went away (``... | head``): stops quietly
=====  ====================================================================================

:func:`run_main` wraps a command's ``main``; :func:`guard` (first thing in a script) covers the
moment before it, while the script is still importing. Before that, while the interpreter
itself starts, a Ctrl-C is CPython's to report (with a traceback); a launcher that blocks
SIGINT across ``exec`` has it delivered once the guard is in place.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any, NoReturn

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_NO_SOLUTION = 3
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141

EPILOG = ("exit codes: 0 success, 1 a check failed, 2 bad input or environment (one line on "
          "stderr), 3 no solution in time, 70 internal error (the gateway's owner died), 74 "
          "journal write failed (the gateway stopped: restart it), 130 interrupted (Ctrl-C), "
          "141 output pipe closed")
"""The exit codes in one line, for every command's ``--help``."""


_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
"""Errors that only a write gets: without a file name, the output it was writing."""


class UsageError(Exception):
    """Bad input: the command prints ``PROG: <message>`` and exits with code 2."""


class CommandParser(argparse.ArgumentParser):
    """An argument parser whose ``--help`` ends with the exit codes (:data:`EPILOG`) and
    whose own output (``--help``, ``--version``, usage) fails like any other: argparse
    drops an OSError there, so ``--help > /dev/full`` would say nothing and exit 0."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("epilog", EPILOG)
        super().__init__(*args, **kwargs)

    def _print_message(self, message: str, file: Any = None) -> None:
        if message:
            (file or sys.stderr).write(message)


def quiet_stdout() -> None:
    """Point standard output at /dev/null, so that nothing more (nor Python's final flush)
    fails on a closed pipe or a full device."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)
    except (OSError, ValueError, AttributeError):  # no real file descriptor (captured output)
        pass


def _say(prog: str, message: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(f"{prog}: {message}", file=sys.stderr, flush=True)


_CTRL_C: list[bool] = []
"""Not empty once a Ctrl-C (SIGINT) came: from then on an exception that ends the command is
the interrupt's doing. A library may turn the KeyboardInterrupt raised inside it into an
error of its own (pydantic-core building a validator: ``SchemaError: ... KeyboardInterrupt``)."""


def _note_ctrl_c(signum: int, frame: Any) -> None:
    """SIGINT: noted in :data:`_CTRL_C`, then Python's own handler (KeyboardInterrupt)."""
    _CTRL_C.append(True)
    signal.default_int_handler(signum, frame)


def _ending(prog: str, exc: BaseException) -> int:
    """The exit code for ``exc`` escaping a command (its one line printed); re-raises what is
    no user-facing ending (a bug keeps its traceback), unless a Ctrl-C came before it."""
    if isinstance(exc, UsageError):
        _say(prog, str(exc))
        return EXIT_BAD_INPUT
    if isinstance(exc, KeyboardInterrupt):
        _say(prog, "interrupted")
        return EXIT_INTERRUPTED
    if isinstance(exc, BrokenPipeError):
        quiet_stdout()
        return EXIT_BROKEN_PIPE
    if isinstance(exc, OSError):
        if exc.filename is None and _flush_stdout(prog) is not None:
            return EXIT_BAD_INPUT  # it was standard output that failed (said so)
        where = f"{exc.filename}: " if exc.filename else ""
        if not where and exc.errno in _NO_SPACE:
            where = "cannot write the output: "
        _say(prog, f"{where}{exc.strerror or exc}")
        return EXIT_BAD_INPUT
    if _CTRL_C and isinstance(exc, Exception):
        _say(prog, "interrupted")
        return EXIT_INTERRUPTED
    raise exc


def _flush_stdout(prog: str) -> int | None:
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        quiet_stdout()
        return EXIT_BROKEN_PIPE
    except OSError as exc:
        quiet_stdout()
        _say(prog, f"cannot write standard output: {exc.strerror or exc}")
        return EXIT_BAD_INPUT
    return None


GRACE_S = 5.0
"""After Ctrl-C a command has this long to stop cleanly; then it ends at once with 130 (a
KeyboardInterrupt can be swallowed where Python cannot raise it, e.g. in a gc callback, or
wait behind a long computation)."""


def _give_up(prog: str) -> None:
    _say(prog, f"interrupted (did not stop within {GRACE_S:g} s)")
    try:
        _stop_children(at_once=True)
    finally:  # the last resort ends the process, whatever stopping the children did
        os._exit(EXIT_INTERRUPTED)


def _stop_children(at_once: bool) -> None:
    """Before ``os._exit`` (which runs no ``atexit``): stop the children the command
    started (:mod:`fleetgate.userio.children`, if it was ever imported: else there are none),
    ``at_once``: SIGKILL right after SIGTERM."""
    children = sys.modules.get("fleetgate.userio.children")
    if children is not None:
        children.stop_all(grace_s=0.0 if at_once else children.STOP_GRACE_S)


@contextlib.contextmanager
def _bounded_interrupts(prog: str) -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt as usual and starts :data:`GRACE_S` of grace (only
    where Python's own handler is in place, in the main thread); a swallowed one is sent
    again (:func:`_interrupt_again`)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) not in (signal.default_int_handler,
                                                        _note_ctrl_c)):
        yield
        return
    started: list[threading.Timer] = []

    def on_sigint(signum: int, frame: Any) -> None:
        if not started:
            started.append(threading.Timer(GRACE_S, _give_up, args=(prog,)))
            started[0].daemon = True
            started[0].start()
        _note_ctrl_c(signum, frame)

    previous = signal.signal(signal.SIGINT, on_sigint)
    previous_hook, sys.unraisablehook = sys.unraisablehook, _interrupt_again
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = previous_hook


def _interrupt_again(info: Any) -> None:
    """``sys.unraisablehook``: a KeyboardInterrupt that Python had to swallow (raised in a gc
    callback or a finaliser) is not printed; SIGINT is sent again a moment later."""
    if not isinstance(info.exc_value, KeyboardInterrupt):
        sys.__unraisablehook__(info)
        return
    again = threading.Timer(0.05, signal.raise_signal, args=(signal.SIGINT,))
    again.daemon = True
    again.start()


def call(prog: str, main: Callable[..., int | None], *args: Any) -> int:
    """Run ``main(*args)`` and return the process's exit code: its own (None is 0), or the
    documented one for Ctrl-C, a closed pipe, an OSError or a :class:`UsageError`, after one
    line on stderr. Standard output is flushed here, so that a full device is reported too."""
    try:
        with _bounded_interrupts(prog):
            _deliver_held_interrupts()
            code = main(*args) or EXIT_OK
    except (UsageError, KeyboardInterrupt, OSError) as exc:
        code = _ending(prog, exc)
    except SystemExit as exc:  # argparse's --help, --version and usage errors
        if exc.code is not None and not isinstance(exc.code, int):
            _say(prog, str(exc.code))
        code = exc.code if isinstance(exc.code, int) else EXIT_OK if exc.code is None else 1
    except Exception as exc:  # a bug keeps its traceback, unless a Ctrl-C came before it
        if not _CTRL_C:
            raise
        code = _ending(prog, exc)
    flushed = _flush_stdout(prog)
    return code if flushed is None else flushed


def run_main(prog: str, main: Callable[..., int | None], *args: Any) -> NoReturn:
    """``sys.exit(call(prog, main, *args))``: the last line of a script."""
    guard(prog)
    sys.exit(call(prog, main, *args))


def guard(prog: str) -> None:
    """From now on an exception that escapes to the top (e.g. Ctrl-C while a script still
    imports, before :func:`run_main`) ends the process with its documented code and one line;
    others keep their traceback."""

    def last_words(kind: type[BaseException], exc: BaseException, tb: Any) -> None:
        try:
            code = _ending(prog, exc)
        except BaseException:
            sys.__excepthook__(kind, exc, tb)
            return
        _flush_stdout(prog)
        _stop_children(at_once=False)
        os._exit(code)

    sys.excepthook = last_words
    sys.unraisablehook = _interrupt_again
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
        signal.signal(signal.SIGINT, _note_ctrl_c)
    _deliver_held_interrupts()


def _deliver_held_interrupts() -> None:
    """Unblock SIGINT. Whoever starts a command may block it (a blocked signal stays
    blocked across ``exec``) so that a Ctrl-C during the interpreter's own start-up, before
    any code of ours runs and where CPython prints a traceback for it, waits until the guard
    is in place: it is delivered here, and ends the command with one line and 130."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
