"""The dashboard's tree view: the trees' history as JSON for ``static/tree.js``.

Two routes, the same for a running cell (``feeder run --ui``: the recorder's in-memory
view, published by the tick thread) and for a past run (``feeder replay --ui``: the event
log): ``GET /api/tree/nodes`` (every recorded node, once; again when ``nodes`` grows) and
``GET /api/tree/at?t=SECONDS`` (the statuses and the blackboard then; without ``t``, the
latest). Both only read immutable data: nothing here touches the cell.
"""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from feeder_bt.records.treelog import TraceView
from feeder_bt.ui.responses import json_response, refuse

Guard = Callable[[Request], Response | None]


def nodes_json(view: TraceView) -> dict:
    """Every node: id, parent (-1 for a root), tree, name, shape, class."""
    return {"ok": True, "nodes": [[n.id, n.parent, n.tree, n.name, *n.kind.split(":", 1)]
                                  for n in view.nodes]}


def state_json(view: TraceView, t: float | None, live: bool) -> dict:
    """The state at ``t`` (None: the latest) with the span and marks of the timeline."""
    t0, t1 = view.span
    at = t1 if t is None else min(max(t, t0), t1)
    state = view.at(at)
    return {"ok": True, "t": round(at, 3), "span": [round(t0, 3), round(t1, 3)], "live": live,
            "tree": state.tree, "nodes": len(view.nodes), "statuses": list(state.statuses),
            "board": state.board, "marks": [[round(m, 3), what] for m, what in view.marks]}


def tree_routes(view: Callable[[], TraceView | None], guard: Guard, live: bool) -> list[Route]:
    """The two routes; ``guard`` answers a request that may not read (None: it may)."""

    def checked(fn: Callable[[Request, TraceView], Response]
                ) -> Callable[[Request], Awaitable[Response]]:
        async def handler(request: Request) -> Response:
            denied = guard(request)
            if denied is not None:
                return denied
            v = view()
            if v is None:
                return refuse("no trees recorded yet", 404)
            return fn(request, v)
        return handler

    def at(request: Request, v: TraceView) -> Response:
        text = request.query_params.get("t")
        t = None
        if text:
            try:
                t = float(text[:32])
            except ValueError:
                t = math.nan
            if not math.isfinite(t):
                return refuse("t must be a number of seconds", 400)
        return json_response(state_json(v, t, live))

    return [Route("/api/tree/nodes", checked(lambda r, v: json_response(nodes_json(v)))),
            Route("/api/tree/at", checked(at))]
