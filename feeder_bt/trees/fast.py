"""Ticking a py_trees tree without its generators: the same steps in the same order.

py_trees ticks a tree through nested generators: every node a tick visits is yielded up
through each of its ancestors' generators, and every ``tick`` and ``stop`` formats a debug
line whether or not debug logging is on. On the lenses hour that overhead was most of a
tick (0.21 ms). ``tick_once(root)`` walks the tree with plain calls instead, node class by
node class as py_trees' own ``tick`` and ``stop`` do (initialise, update, stop, status,
``current_child``, the invalidation of siblings), so every behaviour sees the same calls in
the same order and a run's results are unchanged (``tests/trees/test_fast_tick.py``
compares the two on random trees). A node whose class overrides ``tick`` or ``stop`` with
code this module does not know is ticked or stopped by that code; a class may offer
``fast_tick(self)`` (``trees.build.Loop`` does). py_trees' debug log lines are not written.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from py_trees.behaviour import Behaviour
from py_trees.common import ParallelPolicy, Status
from py_trees.composites import Composite, Parallel, Selector, Sequence
from py_trees.decorators import Decorator

RUNNING, SUCCESS, FAILURE, INVALID = Status.RUNNING, Status.SUCCESS, Status.FAILURE, \
    Status.INVALID
_VALID = frozenset(Status)

Handler = Callable[[Any], None]
StopHandler = Callable[[Any, Status], None]


def tick_once(root: Behaviour) -> None:
    """One tick of the tree under ``root``, as ``root.tick_once()`` would do it."""
    _tick(root)


def _tick(node: Any) -> None:
    fn = _TICKS.get(type(node))
    if fn is None:
        fn = _resolve(type(node))[0]
    fn(node)


def stop(node: Any, new_status: Status) -> None:
    """``node.stop(new_status)``, without py_trees' debug formatting where the class is known."""
    fn = _STOPS.get(type(node))
    if fn is None:
        fn = _resolve(type(node))[1]
    fn(node, new_status)


def _checked(node: Any, new_status: Any) -> Status:
    if new_status not in _VALID:
        node.logger.error(f"A behaviour returned an invalid status, setting to INVALID "
                          f"[{new_status}][{node.name}]")
        return INVALID
    return new_status


# ----------------------------------------------------------------------- ticks
def _leaf(node: Any) -> None:
    """``Behaviour.tick``."""
    if node.status != RUNNING:
        node.initialise()
    new_status = node.update()
    if new_status not in _VALID:
        new_status = _checked(node, new_status)
    if new_status != RUNNING:
        stop(node, new_status)
    node.status = new_status


def _decorator(node: Any) -> None:
    """``Decorator.tick``."""
    if node.status != RUNNING:
        node.initialise()
    _tick(node.decorated)
    new_status = node.update()
    if new_status not in _VALID:
        new_status = _checked(node, new_status)
    if new_status != RUNNING:
        stop(node, new_status)
    node.status = new_status


def _sequence(node: Any) -> None:
    """``Sequence.tick``."""
    children = node.children
    index = 0
    if node.status != RUNNING:
        node.current_child = children[0] if children else None
        for child in children:
            if child.status != INVALID:
                stop(child, INVALID)
        node.initialise()
    elif node.memory and node.current_child is not None:
        index = children.index(node.current_child)
    else:
        node.current_child = children[0] if children else None
    if not children:
        node.current_child = None
        stop(node, SUCCESS)
        return
    for child in children[index:]:
        _tick(child)
        status = child.status
        if status != SUCCESS:
            if not node.memory:             # kill the dangling runners after it
                for later in children[index + 1:]:
                    if later.status != INVALID:
                        stop(later, INVALID)
            if status != RUNNING:
                stop(node, status)
            else:
                node.status = status
            return
        if index + 1 < len(children):
            node.current_child = children[index + 1]
            index += 1
    stop(node, SUCCESS)


def _selector(node: Any) -> None:
    """``Selector.tick``."""
    children = node.children
    if node.status != RUNNING:
        node.current_child = children[0] if children else None
        node.initialise()
    if not children:
        node.current_child = None
        stop(node, FAILURE)
        return
    if node.memory:
        index = children.index(node.current_child)
        for child in children[:index]:
            if child.status != INVALID:
                stop(child, INVALID)
    else:
        index = 0
    previous = node.current_child
    for child in children[index:]:
        _tick(child)
        status = child.status
        if status == RUNNING or status == SUCCESS:
            node.current_child = child
            if previous is None or previous != child:
                passed = False              # interrupted: invalidate the lower priorities
                for other in children:
                    if passed and other.status != INVALID:
                        stop(other, INVALID)
                    passed = True if other == child else passed
            if child.status == SUCCESS:
                stop(node, child.status)
            else:
                node.status = child.status
            return
    stop(node, FAILURE)
    node.current_child = children[-1]


def _parallel(node: Any) -> None:
    """``Parallel.tick``."""
    node.validate_policy_configuration()
    children = node.children
    if node.status != RUNNING:
        for child in children:
            if child.status != INVALID:
                stop(child, INVALID)
        node.current_child = None
        node.initialise()
    if not children:
        node.current_child = None
        stop(node, SUCCESS)
        return
    policy = node.policy
    sync = policy.synchronise
    for child in children:
        if sync and child.status == SUCCESS:
            continue
        _tick(child)
    new_status = RUNNING
    node.current_child = children[-1]
    failed = next((c for c in children if c.status == FAILURE), None)
    if failed is not None:
        node.current_child = failed
        new_status = FAILURE
    elif isinstance(policy, ParallelPolicy.SuccessOnAll):
        if all(c.status == SUCCESS for c in children):
            new_status = SUCCESS
            node.current_child = children[-1]
    elif isinstance(policy, ParallelPolicy.SuccessOnOne):
        for child in reversed(children):
            if child.status == SUCCESS:
                new_status = SUCCESS
                node.current_child = child
                break
    elif isinstance(policy, ParallelPolicy.SuccessOnSelected):
        if all(c.status == SUCCESS for c in policy.children):
            new_status = SUCCESS
            node.current_child = policy.children[-1]
    else:
        raise RuntimeError(f"this parallel has been configured with an unrecognised policy "
                           f"[{type(policy)}]")
    if new_status != RUNNING:
        stop(node, new_status)
    node.status = new_status


def _generator(node: Any) -> None:
    """A class whose ``tick`` this module does not know: its own generator."""
    for _ in node.tick():
        pass


# ----------------------------------------------------------------------- stops
def _stop_leaf(node: Any, new_status: Status) -> None:
    """``Behaviour.stop``."""
    node.terminate(new_status)
    node.status = new_status
    node.iterator = node.tick()


def _stop_composite(node: Any, new_status: Status) -> None:
    """``Composite.stop`` (and ``Sequence.stop``, ``Selector.stop``: it with a log line)."""
    if new_status == INVALID:
        node.current_child = None
        for child in node.children:
            if child.status != INVALID:
                stop(child, new_status)
    node.terminate(new_status)
    node.status = new_status
    node.iterator = node.tick()


def _stop_parallel(node: Any, new_status: Status) -> None:
    """``Parallel.stop``: the running children first."""
    for child in node.children:
        if child.status == RUNNING:
            stop(child, INVALID)
    _stop_composite(node, new_status)


def _stop_decorator(node: Any, new_status: Status) -> None:
    """``Decorator.stop``."""
    node.terminate(new_status)
    if new_status == INVALID:
        stop(node.decorated, new_status)
    if node.decorated.status == RUNNING:
        stop(node.decorated, INVALID)
    node.status = new_status


def _own_stop(node: Any, new_status: Status) -> None:
    node.stop(new_status)


_KNOWN_TICKS: dict[Any, Handler] = {
    Behaviour.tick: _leaf, Decorator.tick: _decorator, Sequence.tick: _sequence,
    Selector.tick: _selector, Parallel.tick: _parallel}
_KNOWN_STOPS: dict[Any, StopHandler] = {
    Behaviour.stop: _stop_leaf, Composite.stop: _stop_composite,
    Sequence.stop: _stop_composite, Selector.stop: _stop_composite,
    Parallel.stop: _stop_parallel, Decorator.stop: _stop_decorator}
_TICKS: dict[type, Handler] = {}
_STOPS: dict[type, StopHandler] = {}


def _resolve(cls: type) -> tuple[Handler, StopHandler]:
    """How to tick and stop nodes of ``cls``, found once per class."""
    own = getattr(cls, "fast_tick", None)
    tick_fn = own if own is not None else _KNOWN_TICKS.get(cls.tick, _generator)
    stop_fn = _KNOWN_STOPS.get(cls.stop, _own_stop)
    _TICKS[cls], _STOPS[cls] = tick_fn, stop_fn
    return tick_fn, stop_fn


def tick_child(node: Any) -> None:
    """Tick one node of a tree (for a class's own ``fast_tick``)."""
    _tick(node)
