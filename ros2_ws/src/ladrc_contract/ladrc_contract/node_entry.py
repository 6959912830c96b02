"""The one entry of every node, and the one place that handles stop signals.

A node's ``main`` is :func:`run_node`::

    def main(argv=None) -> int:
        return run_node('follow_node', make_node, run, args=argv, zero=publish_zero)

:func:`run_node` does, in this order:

1. installs the SIGINT/SIGTERM handlers (before anything else: a stop signal during the start
   is not lost); a stop signal only sets :attr:`NodeRun.stop_requested` and calls the hooks of
   :meth:`NodeRun.on_stop`, so the node still has a valid ROS context for its zero command
   (rclpy's own handlers would shut the context down at once: ``SignalHandlerOptions.NO``);
2. ``check_args(args)`` (a problem: one line, exit 2), ``rclpy.init(args=args)``;
3. builds the node with ``make_node()``; any exception there is one line on stderr, exit
   :data:`EXIT_CONFIG` (2), no traceback (:class:`StartError` carries its own line);
4. ``run(node, node_run)`` -> exit code (``None``: 0); the default :func:`spin` runs the
   node's callbacks until a stop signal; a node's own real-time loop runs in ``run``, on the
   main thread, and reads ``node_run.stop_requested`` (a plain attribute) each iteration.
   A :class:`StartError` in ``run``: its line, exit 2; ``ExternalShutdownException``: a stop
   (reason ``external shutdown``), exit 0; any other exception: one line
   ``NAME: stopped by TYPE: TEXT``, exit :data:`EXIT_FAILED` (1);
5. however 4 ended, while the context is still valid: ``zero(node, reason)`` (the node's zero
   command), then the clean-ups of :meth:`NodeRun.defer` (last first), then
   ``node.destroy_node()``, ``rclpy.try_shutdown()``;
6. last, :func:`ignore_stop_signals`.

Exit codes: 0 the run ended (by itself, or stopped by SIGINT/SIGTERM after its zero command:
the bring-up stops every node that way at the end of a run); 1 the node failed while running;
2 bad configuration or arguments (the node's work did not start); a node's own codes (3: lock
step aborted) from its ``run``. Processes that are no nodes take their stop signals here too: a
supervisor's ``main`` through :func:`take_stop_signals`, a run inside a command (a sweep, a
conformance run, the bus emulator) through :func:`stop_signals`, a worker through
:func:`ignore_stop_signals`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import signal
import sys
import time
from typing import Any, TypeVar

EXIT_OK = 0
"""The run ended: by itself, or stopped by a stop signal after its zero command."""
EXIT_FAILED = 1
"""The node failed while running (an exception out of its run; the zero command was sent)."""
EXIT_CONFIG = 2
"""Bad arguments, parameters or configuration: the node did not run."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

N = TypeVar('N')


class StartError(Exception):
    """The node cannot start with this configuration; ``str(exc)`` is the one line to print."""


class NodeRun:
    """A node's run as its code sees it: the stop request and the deferred clean-ups.

    ``stop_requested`` is a plain attribute (a loop at 2 kHz reads it every tick); ``stop_reason``
    names what stopped the run (``SIGINT``, ``SIGTERM``, ``external shutdown``; ``shutdown``
    while nothing asked).
    """

    __slots__ = ('stop_requested', 'stop_reason', '_hooks', '_deferred')

    def __init__(self) -> None:
        self.stop_requested = False
        self.stop_reason = 'shutdown'
        self._hooks: list[Callable[[], Any]] = []
        self._deferred: list[tuple[Callable[..., Any], tuple]] = []

    def request_stop(self, reason: str) -> None:
        """Ask the run to stop (a stop signal calls this); only the first request counts."""
        if self.stop_requested:
            return
        self.stop_reason = reason
        self.stop_requested = True
        for hook in self._hooks:
            hook()

    def on_stop(self, hook: Callable[[], Any]) -> None:
        """Call ``hook()`` once, at the stop request (in the signal handler: set a flag).

        Called at once when the stop was requested already.
        """
        self._hooks.append(hook)
        if self.stop_requested:
            hook()

    def wait(self, timeout_s: float) -> bool:
        """Sleep up to ``timeout_s`` or until a stop is requested; return ``stop_requested``."""
        end = time.monotonic() + timeout_s
        while not self.stop_requested:
            left = end - time.monotonic()
            if left <= 0:
                break
            time.sleep(min(left, 0.05))
        return self.stop_requested

    def defer(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` after the zero command, before the node is destroyed (last first)."""
        self._deferred.append((fn, args))

    def _run_deferred(self, name: str) -> None:
        while self._deferred:
            fn, args = self._deferred.pop()
            try:
                fn(*args)
            except Exception as exc:  # noqa: BLE001 - the others still run
                _line(name, f'clean-up {getattr(fn, "__qualname__", fn)}: '
                            f'{type(exc).__name__}: {exc}')


def _line(name: str, text: str) -> None:
    print(f'{name}: {" ".join(str(text).split())}', file=sys.stderr, flush=True)


def spin(node: Any, run: NodeRun, period_s: float = 0.1) -> int:
    """Execute the node's callbacks until a stop is requested (the default run).

    ``spin_once`` with a timeout, so a stop signal (handled between two waits) ends it within
    ``period_s``.
    """
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while not run.stop_requested:
            executor.spin_once(timeout_sec=period_s)
    finally:
        executor.shutdown(timeout_sec=1.0)
    return EXIT_OK


def run_node(name: str, make_node: Callable[[], N],
             run: Callable[[N, NodeRun], int | None] = spin, *,
             args: list[str] | None = None,
             check_args: Callable[[list[str]], str] | None = None,
             zero: Callable[[N, str], Any] | None = None) -> int:
    """Start, run and end one node (see the module docstring); return the exit code.

    ``name`` prefixes every line printed; ``args``: the command line (``None``: ``sys.argv``);
    ``check_args(argv)`` returns why the arguments cannot be taken ('' when they can);
    ``zero(node, reason)`` sends the node's zero / safe command, on every path once the node
    exists.
    """
    node_run = take_stop_signals()
    try:
        return _run(name, make_node, run, args, check_args, zero, node_run)
    finally:
        ignore_stop_signals()


def _run(name, make_node, run, args, check_args, zero, node_run: NodeRun) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    if check_args is not None:
        problem = check_args(list(sys.argv if args is None else args))
        if problem:
            _line(name, problem)
            return EXIT_CONFIG
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - e.g. rcl cannot parse the arguments
        _line(name, f'cannot start: {type(exc).__name__}: {exc}')
        return EXIT_CONFIG
    node = None
    try:
        try:
            node = make_node()
        except StartError as exc:
            _line(name, str(exc))
            return EXIT_CONFIG
        except Exception as exc:  # noqa: BLE001 - one line, no traceback
            _line(name, f'cannot start: {type(exc).__name__}: {exc}')
            return EXIT_CONFIG
        try:
            code = run(node, node_run)
        except StartError as exc:
            _line(name, str(exc))
            return EXIT_CONFIG
        except ExternalShutdownException:
            node_run.request_stop('external shutdown')
            return EXIT_OK
        except Exception as exc:  # noqa: BLE001 - the zero command follows; one line
            _line(name, f'stopped by {type(exc).__name__}: {exc}')
            return EXIT_FAILED
        return EXIT_OK if code is None else int(code)
    finally:
        if node is not None:
            if zero is not None:
                try:
                    zero(node, node_run.stop_reason)
                except Exception as exc:  # noqa: BLE001 - the context may be gone already
                    _line(name, f'zero command: {type(exc).__name__}: {exc}')
            node_run._run_deferred(name)
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001, S110 - going down anyway
                pass
        rclpy.try_shutdown()


def _install(node_run: NodeRun) -> dict:
    """Make SIGINT and SIGTERM request ``node_run``'s stop; return the handlers they had."""
    def _handler(signum: int, _frame: Any) -> None:
        node_run.request_stop(signal.Signals(signum).name)

    return {sig: signal.signal(sig, _handler) for sig in STOP_SIGNALS}


def take_stop_signals() -> NodeRun:
    """From here to the process's end, SIGINT and SIGTERM request the returned run's stop.

    A process's ``main`` that is no node (a bring-up supervisor) polls ``stop_requested``.
    """
    _install(run := NodeRun())
    return run


@contextlib.contextmanager
def stop_signals() -> Iterator[NodeRun]:
    """Within the block, SIGINT and SIGTERM request the yielded run's stop; then as before.

    For processes that are no nodes (the bring-up's supervisors, the bus emulator): the handler
    runs in the main thread between two bytecodes and calls the :meth:`NodeRun.on_stop` hooks
    (set a flag, forward the signal); :meth:`NodeRun.defer` is not run here.
    """
    previous = _install(stop := NodeRun())
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def ignore_stop_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> None:
    """Ignore ``signals`` (SIGINT and SIGTERM) from here to the process's end.

    A node's last step: after rclpy is shut down, Python's finalization puts the default action
    back for every signal with a Python handler; a stop signal in that window (the bring-up
    stopping every node at the end of a run, while this one is already exiting) would end the
    process as killed after it did everything right. An ignored signal stays ignored through
    finalization (CPython's ``_PySignal_Fini`` leaves ``SIG_IGN`` alone). Also a worker's first
    step, for the signals its parent handles.
    """
    for sig in signals:
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread, or an exotic platform
            pass
