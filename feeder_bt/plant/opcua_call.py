"""Calling the cell's OPC UA methods without losing a refusal's reason.

The server answers a refused call with a bad status code *and* its one line of text as the
output argument (plant/opcua.py ``_refuse``), but asyncua's ``Node.call_method`` raises on
the status alone and drops the outputs (so does ``call_method_full``: both check the status
before returning). :func:`call` sends the same request and keeps both: the error is the status
code's own exception class (so ``except BadUserAccessDenied`` still works) with the
server's text in its message."""

from __future__ import annotations

from typing import Any

from asyncua import Node, ua
from asyncua.common.methods import to_variant
from asyncua.ua.uaerrors import UaStatusCodeError


class Refused(UaStatusCodeError):
    """A bad status with the server's reason; ``code`` and ``reason`` kept apart."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(code)
        self.code, self.reason = code, reason

    def __str__(self) -> str:
        return f"{self.reason} ({super().__str__()})"


async def call(parent: Node, method: Any, *args: Any) -> Any:
    """``parent.call_method(method, *args)``, raising :class:`Refused` (a subclass of the
    status code's asyncua error) with the reason the server gave."""
    if isinstance(method, str | ua.QualifiedName):
        method = (await parent.get_child(method)).nodeid
    req = ua.CallMethodRequest()
    req.ObjectId, req.MethodId, req.InputArguments = parent.nodeid, method, to_variant(*args)
    res = (await parent.session.call([req]))[0]         # asyncua's own request, unchecked
    res.OutputArguments = [v.Value for v in res.OutputArguments or []]
    if not res.StatusCode.is_good():
        outs = [str(v) for v in (res.OutputArguments or []) if v is not None]
        code = res.StatusCode.value
        base = UaStatusCodeError(code).__class__          # BadUserAccessDenied, ...
        err = type(base.__name__, (Refused, base), {})(code, "; ".join(outs) or "refused")
        raise err
    outs = res.OutputArguments or []
    if not outs:
        return None
    return outs[0] if len(outs) == 1 else outs
