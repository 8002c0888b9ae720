"""The ``touch`` device: a Geomagic / 3D Systems Touch stylus through the OpenHaptics HD API (``libHD``).

``libHD`` is loaded with ctypes when a device connects, so nothing here needs the SDK at import time or
at build time. Lookup order: the ``path`` argument, the ``SURROL_LIBHD`` environment variable, the
system library path (``ctypes.util.find_library("HD")``, then ``libHD.so``). Without it the error says
what to install.

One or two devices: ``side="left"`` / ``"right"`` opens the device named ``Left`` / ``Right`` in
Touch_Setup (as the SurRoL-v2 wrapper does), ``side=None`` the default device. All devices of one
library share its servo scheduler: it must be stopped while a device is initialised, so the devices of
a library are counted and the scheduler restarted around each ``hdInitDevice``.

Each :meth:`TouchDevice.read` runs one synchronous scheduler callback (``hdScheduleSynchronous``) that
reads the current position (mm), gimbal angles (rad) and buttons inside one servo frame
(``hdBeginFrame``/``hdEndFrame``) — the only place where HD state is consistent — and checks
``hdGetError``; a device error (unplugged, communication lost) becomes a :class:`DeviceError`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading
import time
from pathlib import Path

import numpy as np

from surrol_data.collect.devices.base import BUTTON_TAKEOVER, Device, DeviceError, DeviceFrame

LIBRARY_ENV = "SURROL_LIBHD"
INSTALL_HINT = ("install the OpenHaptics SDK for Linux (3D Systems 'OpenHaptics Developer Edition', which "
                "ships libHD.so) and the Touch device driver, run Touch_Setup to name the devices, then either put "
                f"libHD.so on the library path or set {LIBRARY_ENV}=/path/to/libHD.so")
SIDES = {"left": b"Left", "right": b"Right", None: None}   # None: HD_DEFAULT_DEVICE

# hdDefines.h
HD_SUCCESS = 0x0000
HD_INVALID_HANDLE = 0xFFFFFFFF
HD_CURRENT_BUTTONS = 0x2000
HD_CURRENT_POSITION = 0x2050
HD_CURRENT_GIMBAL_ANGLES = 0x2150
HD_CALLBACK_DONE = 0
HD_DEFAULT_SCHEDULER_PRIORITY = 500


class HDErrorInfo(ctypes.Structure):
    _fields_ = [("errorCode", ctypes.c_uint), ("internalErrorCode", ctypes.c_int), ("hHD", ctypes.c_uint)]


HDSchedulerCallback = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p)


def find_libhd(path: str | Path | None = None) -> str:
    """Path or soname of libHD to load, or DeviceError naming what to install."""
    if path is not None or os.environ.get(LIBRARY_ENV):
        chosen = Path(path if path is not None else os.environ[LIBRARY_ENV])
        if not chosen.is_file():
            origin = "the path given" if path is not None else f"{LIBRARY_ENV}"
            raise DeviceError(f"libHD not found at {chosen} ({origin}); {INSTALL_HINT}")
        return str(chosen)
    found = ctypes.util.find_library("HD")
    return found or "libHD.so"


def _declare(lib: ctypes.CDLL) -> None:
    c = ctypes
    signatures = {
        "hdInitDevice": ([c.c_char_p], c.c_uint),
        "hdDisableDevice": ([c.c_uint], None),
        "hdMakeCurrentDevice": ([c.c_uint], None),
        "hdBeginFrame": ([c.c_uint], None),
        "hdEndFrame": ([c.c_uint], None),
        "hdGetDoublev": ([c.c_uint, c.POINTER(c.c_double)], None),
        "hdGetIntegerv": ([c.c_uint, c.POINTER(c.c_int)], None),
        "hdStartScheduler": ([], None),
        "hdStopScheduler": ([], None),
        "hdScheduleSynchronous": ([HDSchedulerCallback, c.c_void_p, c.c_ushort], None),
        "hdGetError": ([], HDErrorInfo),
    }
    missing = []
    for name, (args, res) in signatures.items():
        try:
            fn = getattr(lib, name)
        except AttributeError:
            missing.append(name)
            continue
        fn.argtypes, fn.restype = args, res
    if missing:
        raise DeviceError(f"{lib._name} lacks {missing}: not the OpenHaptics HD library; {INSTALL_HINT}")
    if hasattr(lib, "hdGetErrorString"):   # optional: only used to word errors
        lib.hdGetErrorString.argtypes, lib.hdGetErrorString.restype = [c.c_uint], c.c_char_p


class _HDLibrary:
    """One loaded libHD and the devices open on it (they share its scheduler)."""

    _loaded: dict[str, _HDLibrary] = {}   # per library file: the HD API is process-global state
    _lock = threading.Lock()

    def __init__(self, where: str):
        try:
            self.lib = ctypes.CDLL(where)
        except OSError as e:
            raise DeviceError(f"cannot load libHD ({where}: {e}); {INSTALL_HINT}") from None
        _declare(self.lib)
        self.where = where
        self.handles: set[int] = set()
        self.scheduler_running = False

    @classmethod
    def get(cls, where: str) -> _HDLibrary:
        with cls._lock:
            if where not in cls._loaded:
                cls._loaded[where] = cls(where)
            return cls._loaded[where]

    def error(self) -> tuple[int, int, str] | None:
        info = self.lib.hdGetError()
        if info.errorCode == HD_SUCCESS:
            return None
        text = ""
        if hasattr(self.lib, "hdGetErrorString"):
            raw = self.lib.hdGetErrorString(info.errorCode)
            text = raw.decode(errors="replace") if raw else ""
        return int(info.errorCode), int(info.internalErrorCode), text

    def open(self, config: bytes | None) -> int:
        label = config.decode() if config else "the default device"
        with self._lock:
            if self.scheduler_running:   # hdInitDevice must not run while the servo loop does
                self.lib.hdStopScheduler()
                self.scheduler_running = False
            handle = int(self.lib.hdInitDevice(config))
            err = self.error()
            if handle == HD_INVALID_HANDLE or err is not None:
                code = f" (HD error 0x{err[0]:04x} {err[2]})" if err else ""
                if self.handles:
                    self._start()
                raise DeviceError(f"cannot initialise Touch device {label}{code}: check that it is plugged in, "
                                  "powered, and named in Touch_Setup"
                                  + (" ('Left' / 'Right' for --side left/right)" if config else ""))
            self.handles.add(handle)
            self._start()
            return handle

    def _start(self) -> None:
        self.lib.hdStartScheduler()
        err = self.error()
        if err is not None:
            raise DeviceError(f"cannot start the OpenHaptics servo scheduler (HD error 0x{err[0]:04x} {err[2]})")
        self.scheduler_running = True

    def close(self, handle: int) -> None:
        with self._lock:
            if handle not in self.handles:
                return
            self.handles.discard(handle)
            if self.scheduler_running:
                self.lib.hdStopScheduler()
                self.scheduler_running = False
            self.lib.hdDisableDevice(handle)
            self.error()   # drain: a device that vanished may complain while being disabled
            if self.handles:
                self._start()


class TouchDevice(Device):
    """A Touch stylus: absolute position (mm), gimbal angles (rad) and the two stylus buttons."""

    name = "touch"
    realtime = True

    def __init__(self, side: str | None = None, library: str | Path | None = None, config_name: str | None = None):
        if side not in SIDES:
            raise ValueError(f"touch: side must be 'left', 'right' or None (default device), got {side!r}")
        self.side = side
        self.config = config_name.encode() if config_name else SIDES[side]
        self.library = library
        self._hd: _HDLibrary | None = None
        self._handle: int | None = None
        self._position = np.zeros(3, dtype=np.float64)
        self._gimbal = np.zeros(3, dtype=np.float64)
        self._buttons = ctypes.c_int(0)
        self._pos_buf = (ctypes.c_double * 3)()
        self._gim_buf = (ctypes.c_double * 3)()
        self._read_error: tuple[int, int, str] | None = None
        self._callback = HDSchedulerCallback(self._servo_read)   # kept alive: libHD holds a raw pointer

    def connect(self) -> None:
        if self._handle is not None:
            return
        self._hd = _HDLibrary.get(find_libhd(self.library))
        self._handle = self._hd.open(self.config)

    def _servo_read(self, _user_data) -> int:
        # Runs in the servo thread; must not raise (ctypes would only print the exception).
        lib = self._hd.lib
        lib.hdMakeCurrentDevice(self._handle)
        lib.hdBeginFrame(self._handle)
        lib.hdGetDoublev(HD_CURRENT_POSITION, self._pos_buf)
        lib.hdGetDoublev(HD_CURRENT_GIMBAL_ANGLES, self._gim_buf)
        lib.hdGetIntegerv(HD_CURRENT_BUTTONS, ctypes.byref(self._buttons))
        lib.hdEndFrame(self._handle)
        self._read_error = self._hd.error()
        return HD_CALLBACK_DONE

    def read(self) -> DeviceFrame:
        if self._handle is None:
            raise DeviceError("touch device read before connect()")
        self._read_error = None
        self._hd.lib.hdScheduleSynchronous(self._callback, None, HD_DEFAULT_SCHEDULER_PRIORITY)
        if self._read_error is not None:
            code, internal, text = self._read_error
            raise DeviceError(f"Touch device {self.side or 'default'} stopped answering (HD error 0x{code:04x} "
                              f"{text}, internal {internal}): check its USB/Ethernet cable and power")
        return DeviceFrame(np.array(self._pos_buf[:], dtype=np.float64), np.array(self._gim_buf[:], dtype=np.float64),
                           _buttons(int(self._buttons.value)), time.monotonic())

    def disconnect(self) -> None:
        if self._handle is not None and self._hd is not None:
            handle, self._handle = self._handle, None
            self._hd.close(handle)

    def settings(self) -> dict:
        return {"side": self.side or "default", "config_name": (self.config or b"").decode(),
                "library": self._hd.where if self._hd else str(self.library or "")}


def _buttons(hd_buttons: int) -> int:
    """libHD's button bits → the frame's: buttons 1 and 2 as they are, a third button (HD_DEVICE_BUTTON_3, on
    styli that have one) as the takeover control."""
    return (hd_buttons & 0b11) | (BUTTON_TAKEOVER if hd_buttons & 0b100 else 0)
