"""A stand-in for pypylon's ``pylon`` and ``genicam`` modules with one camera whose node map
and frame counter a test chooses: what Basler's camera emulator cannot be made to do (it
offers the SFNC 2 names and counts 0, 1, 2, ...), such as an older GigE camera with only
SFNC 1 names (``ExposureTimeAbs``, ``GainRaw``), a block id that wraps at 65535 or stays
0, or a camera that cannot say when it is ready for a trigger.

``install(monkeypatch, camera)`` makes ``feeder_bt.hal.camera.pylon`` load this instead of
pypylon. Each trigger (``ExecuteSoftwareTrigger``) queues one frame whose pixels are the
trigger's number, so a test sees which trigger a frame belongs to.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from types import SimpleNamespace

import numpy as np


class GenericException(Exception):
    """genicam.GenericException: what a refused feature raises."""


class Node:
    """One feature: a value, writable or not, with bounds or symbolic values."""

    def __init__(self, value: object, lo: float | None = None, hi: float | None = None,
                 symbolics: Iterable[str] | None = None, writable: bool = True) -> None:
        self._value, self.lo, self.hi, self.writable = value, lo, hi, writable
        self.symbolics = tuple(symbolics) if symbolics is not None else None

    @property
    def Value(self) -> object:  # noqa: N802 - pypylon's name
        return self._value

    @Value.setter
    def Value(self, v: object) -> None:  # noqa: N802
        if self.symbolics is not None and v not in self.symbolics:
            raise GenericException(f"{v!r} is not a valid value : fake.cpp")
        if self.lo is not None and v < self.lo:                     # type: ignore[operator]
            raise GenericException(f"Value = {v} must be equal or greater than {self.lo}")
        if self.hi is not None and v > self.hi:                     # type: ignore[operator]
            raise GenericException(f"Value = {v} must be equal or smaller than {self.hi}")
        self._value = v

    def GetMin(self) -> float | None:  # noqa: N802
        return self.lo

    def GetMax(self) -> float | None:  # noqa: N802
        return self.hi


class EnumNode(Node):
    def GetSymbolics(self) -> tuple[str, ...]:  # noqa: N802
        return self.symbolics or ()


def enum(value: str, *others: str) -> EnumNode:
    return EnumNode(value, symbolics=(value, *others))


def sfnc1_features() -> dict[str, Node]:
    """The node map of an older ace GigE camera (SFNC 1.x names, ranges from its manual's
    kind: exposure in microseconds from 35, GainRaw in steps 300..850)."""
    return {
        "Width": Node(640, 16, 1296), "Height": Node(484, 16, 966),
        "PixelFormat": enum("Mono8", "Mono12", "Mono12Packed"),
        "TriggerSelector": enum("FrameStart", "AcquisitionStart"),
        "TriggerMode": enum("Off", "On"),
        "TriggerSource": enum("Line1", "Software"),
        "TriggerActivation": enum("RisingEdge", "FallingEdge"),
        "ExposureAuto": enum("Off", "Once", "Continuous"),
        "ExposureTimeAbs": Node(3000.0, 35.0, 1_000_000.0),
        "GainAuto": enum("Off", "Once", "Continuous"),
        "GainSelector": enum("All"),
        "GainRaw": Node(500, 300, 850),
        "TriggerDelayAbs": Node(0.0, 0.0, 1_000_000.0),
        "LineSelector": enum("Line1", "Out1"),
        "LineDebouncerTimeAbs": Node(0.0, 0.0, 20_000.0),
        "GevSCPSPacketSize": Node(1500, 220, 9014), "GevSCPD": Node(0, 0, 65535),
    }


class Result:
    """A grab result; an invalid one (nothing retrieved) has no block id."""

    def __init__(self, block: int | None = None, image: np.ndarray | None = None,
                 ok: bool = True) -> None:
        self.block, self.image, self.ok = block, image, ok

    def IsValid(self) -> bool:  # noqa: N802
        return self.block is not None

    def GrabSucceeded(self) -> bool:  # noqa: N802
        return self.ok

    def GetBlockID(self) -> int:  # noqa: N802
        return int(self.block or 0)

    def GetArray(self) -> np.ndarray:  # noqa: N802
        assert self.image is not None
        return self.image

    def GetPixelType(self) -> int:  # noqa: N802
        return PIXEL_MONO8

    def GetErrorDescription(self) -> str:  # noqa: N802
        return "The buffer was incompletely grabbed."

    def Release(self) -> None:  # noqa: N802
        pass


PIXEL_MONO8 = 0x01080001


class Camera:
    """The camera and its instant-camera wrapper in one."""

    def __init__(self, features: dict[str, Node], block_ids: Iterator[int],
                 device_class: str = "BaslerGigE", can_wait: bool = True,
                 serial: str = "21234567", model: str = "acA640-100gm") -> None:
        self.features, self.block_ids = features, block_ids
        self.can_wait = can_wait
        self.device = SimpleNamespace(GetSerialNumber=lambda: serial,
                                      GetModelName=lambda: model,
                                      GetDeviceClass=lambda: device_class)
        self.open = self.grabbing = False
        self.queue: deque[Result] = deque()
        self.triggers = 0
        self.waits = 0                     # WaitForFrameTriggerReady calls it took

    # the node map
    def GetNodeMap(self) -> Camera:  # noqa: N802
        return self

    def GetNode(self, name: str) -> Node | None:  # noqa: N802
        return self.features.get(name)

    def __getattr__(self, name: str) -> Node:
        features = self.__dict__.get("features", {})
        if name in features:
            return features[name]
        raise AttributeError(name)

    # the instant camera
    def Open(self) -> None:  # noqa: N802
        self.open = True

    def Close(self) -> None:  # noqa: N802
        self.open = self.grabbing = False

    def IsOpen(self) -> bool:  # noqa: N802
        return self.open

    def IsCameraDeviceRemoved(self) -> bool:  # noqa: N802
        return False

    def IsGrabbing(self) -> bool:  # noqa: N802
        return self.grabbing

    def StartGrabbing(self, strategy: object) -> None:  # noqa: N802
        self.grabbing = True
        self.queue.clear()

    def StopGrabbing(self) -> None:  # noqa: N802
        self.grabbing = False

    def DestroyDevice(self) -> None:  # noqa: N802
        self.Close()

    def CanWaitForFrameTriggerReady(self) -> bool:  # noqa: N802
        return self.can_wait

    def WaitForFrameTriggerReady(self, timeout_ms: int, handling: object) -> bool:  # noqa: N802
        if not self.can_wait:
            raise GenericException("WaitForFrameTriggerReady is not supported : fake.cpp")
        self.waits += 1
        return True

    def ExecuteSoftwareTrigger(self) -> None:  # noqa: N802
        """One trigger: one frame whose pixels are the trigger's number."""
        self.triggers += 1
        img = np.full((int(self.features["Height"].Value), int(self.features["Width"].Value)),
                      self.triggers % 256, np.uint8)
        self.queue.append(Result(next(self.block_ids), img))

    def RetrieveResult(self, timeout_ms: int, handling: object) -> Result:  # noqa: N802
        return self.queue.popleft() if self.queue else Result()


def modules(camera: Camera) -> tuple[SimpleNamespace, SimpleNamespace]:
    """The fake ``pylon`` and ``genicam`` modules, enumerating ``camera`` alone."""
    factory = SimpleNamespace(EnumerateDevices=lambda: [camera.device],
                              CreateDevice=lambda d: d)
    pylon = SimpleNamespace(
        TlFactory=SimpleNamespace(GetInstance=lambda: factory),
        InstantCamera=lambda device: camera,
        GrabStrategy_OneByOne=0, TimeoutHandling_Return=0, TimeoutHandling_ThrowException=1,
        PixelType_Mono8=PIXEL_MONO8, PixelType_Mono10=0x01100003,
        PixelType_Mono12=0x01100005, PixelType_Mono16=0x01100007)
    genicam = SimpleNamespace(
        GenericException=GenericException,
        IsWritable=lambda node: node is not None and node.writable)
    return pylon, genicam


def install(monkeypatch, camera: Camera) -> None:
    """``PylonSource`` opens ``camera`` through the fake modules."""
    monkeypatch.setattr("feeder_bt.hal.camera.pylon.load_pylon", lambda: modules(camera))


def counting(*start: int, then: int | None = None) -> Iterator[int]:
    """Block ids: ``start`` in turn, then counting on from ``then`` (None: stop)."""
    yield from start
    k = then
    while k is not None:
        yield k
        k += 1
