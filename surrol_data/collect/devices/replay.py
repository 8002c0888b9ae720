"""The ``replay`` device: plays back the frames of recorded device traces, one episode after another.

A replay session takes each episode's seed, mapping settings and operator fields from its trace
(:mod:`surrol_data.collect.devices.trace`), so replaying a trace reproduces the recorded episode: the same
frames through the same mapping into the same seeded env give the same actions and the same outcome.
"""

from __future__ import annotations

from pathlib import Path

from surrol_data.collect.devices.base import Device, DeviceError, DeviceFrame
from surrol_data.collect.devices.trace import DeviceTrace, read_trace, trace_files


class ReplayDevice(Device):
    """Frames of device ``device_index`` of every trace under ``source`` (a file, a trace folder or a dataset)."""

    name = "replay"

    def __init__(self, source: str | Path, device_index: int = 0):
        self.source = Path(source)
        self.device_index = int(device_index)
        self.files = trace_files(self.source)
        self._episode: int | None = None
        self._frames: list[DeviceFrame] = []
        self._next = 0
        self._connected = False

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    @property
    def episodes(self) -> int:
        return len(self.files)

    def trace(self, episode: int) -> DeviceTrace:
        if not 0 <= episode < len(self.files):
            raise DeviceError(f"replay: episode {episode} asked for, {self.source} holds {len(self.files)} traces")
        trace = read_trace(self.files[episode])
        if self.device_index >= trace.n_devices:
            raise DeviceError(f"replay: {self.files[episode]} holds {trace.n_devices} device(s), "
                              f"device {self.device_index} asked for")
        return trace

    def start_episode(self, episode: int) -> DeviceTrace:
        """Play the trace of ``episode`` from its first frame; returns it (its seed, mapping and operator)."""
        trace = self.trace(episode)
        self._episode = episode
        self._frames = trace.device_frames(self.device_index)
        self._next = 0
        return trace

    @property
    def exhausted(self) -> bool:
        """True once every frame of the current episode has been read (the recorded episode ended here)."""
        return self._episode is not None and self._next >= len(self._frames)

    def read(self) -> DeviceFrame:
        if not self._connected:
            raise DeviceError("replay device read before connect()")
        if self._episode is None:
            raise DeviceError("replay: call start_episode(i) before reading")
        if self._next >= len(self._frames):
            raise DeviceError(f"replay: the trace {self.files[self._episode]} ended after {len(self._frames)} frames")
        frame = self._frames[self._next]
        self._next += 1
        return frame

    def settings(self) -> dict:
        return {"source": str(self.source), "device_index": self.device_index, "traces": len(self.files)}
