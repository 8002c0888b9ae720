"""Decode an episode's camera frames from a LeRobot v3 video file with PyAV.

Why PyAV and not torchcodec (lerobot's default decoder when it can load it): torchcodec needs the system's
FFmpeg 4–8 shared libraries; without them every ``LeRobotDataset`` that probes it logs a ~60-line
"Could not load libtorchcodec" traceback before falling back to PyAV anyway. PyAV's wheel bundles FFmpeg (with
the dav1d AV1 decoder), so it works on any machine the package installs on, prints nothing, and needs no
``lerobot`` import (~6 s). Our own ``LeRobotDataset`` calls pass ``video_backend="pyav"`` for the same reason.

An episode is the segment ``[from_timestamp, to_timestamp)`` of a file that holds several episodes back to
back; its frames are the ones whose presentation time falls in that segment (half a frame of tolerance).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from surrol_data.datasets.errors import DatasetError


def _seek(container, at_s: float):
    """The video stream of ``container``, positioned on the key frame at or before ``at_s`` seconds (reading runs
    forward from there)."""
    stream = container.streams.video[0]
    container.seek(max(0, int(at_s / stream.time_base)), stream=stream, backward=True, any_frame=False)
    return stream


def decode_segment(path: str | Path, from_s: float, to_s: float, fps: float, expected: int) -> np.ndarray:
    """The ``expected`` RGB frames (uint8, (T, H, W, 3)) shown between ``from_s`` and ``to_s`` seconds of ``path``."""
    import av

    path = Path(path)
    half = 0.5 / fps
    frames = []
    try:
        with av.open(str(path)) as container:
            stream = _seek(container, from_s - half)
            for frame in container.decode(stream):
                t = float(frame.pts * stream.time_base) if frame.pts is not None else float(frame.time or 0.0)
                if t < from_s - half:
                    continue
                if t >= to_s - half:
                    break
                frames.append(frame.to_ndarray(format="rgb24"))
    except (OSError, av.error.FFmpegError) as e:  # a missing or damaged file
        raise DatasetError(f"{path}: cannot decode the video ({type(e).__name__}: {e}); run `surrol-data validate` "
                           "on the dataset") from None
    if len(frames) != expected:
        raise DatasetError(f"{path}: {len(frames)} frames between {from_s:.3f} s and {to_s:.3f} s, the episode has "
                           f"{expected}; run `surrol-data validate` on the dataset")
    return np.stack(frames)


def segment_digest(path: str | Path, from_s: float, to_s: float, fps: float) -> str:
    """SHA-256 (hex, 32 chars) of the compressed packets shown between ``from_s`` and ``to_s`` seconds of ``path``,
    in presentation order. Nothing is decoded (cheap), and lerobot's concatenation (``merge``) copies packets
    without re-encoding, so a segment keeps its digest wherever it moves; another recording's video does not.
    Raises DatasetError for a missing or damaged file."""
    import hashlib

    import av

    path = Path(path)
    half = 0.5 / fps
    packets: list[tuple[float, bytes]] = []
    try:
        with av.open(str(path)) as container:
            stream = _seek(container, from_s - half)
            for packet in container.demux(stream):
                if packet.pts is None or packet.size == 0:
                    continue
                t = float(packet.pts * stream.time_base)
                decode_t = float(packet.dts * stream.time_base) if packet.dts is not None else t
                if decode_t >= to_s + 1.0:  # packets come in decode order: past the segment for good
                    break
                if from_s - half <= t < to_s - half:
                    packets.append((t, bytes(packet)))
    except (OSError, av.error.FFmpegError) as e:
        raise DatasetError(f"{path}: cannot read the video ({type(e).__name__}: {e})") from None
    digest = hashlib.sha256()
    for _, data in sorted(packets, key=lambda p: p[0]):
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()[:32]
