"""Open the viewer at a time (``testbed view RUN --at SECONDS``): move its time cursor once the recording is in.

rerun 0.41's blueprint has no time cursor (``TimePanel`` sets the timeline, speed and play state only) and
its ``#when=`` URL fragment is read for recordings on a rerun server only, not for a file or the viewer's
gRPC proxy. What moves the cursor is the viewer-control API:

* the native viewer serves it on its gRPC port: :func:`seek_native` calls it through
  ``rerun.experimental.ViewerClient`` (``set_time`` with ``play_state="paused"``);
* the web viewer takes the same requests in the page (``WebHandle.viewer_control``, protobuf bytes; the
  ``rerun --serve-web`` server does not serve the API): :func:`set_time_request` encodes one, for the page
  testbed/recording/webpage.py serves.

The request is ``rerun.viewer_control.v1alpha1.ViewerControlRequest`` with its ``set_time_cursor`` (field 6):
``timeline`` (2, a ``rerun.common.v1alpha1.Timeline``: ``name`` 1), ``time`` (3, a ``TimelineTime``: ``time``
1, nanoseconds on a duration timeline) and ``play_state`` (5, ``PLAY_STATE_PAUSED`` = 1), as rerun 0.41's
``viewer_control.proto`` (embedded in its binaries) defines them.
"""
from __future__ import annotations

import time

TIMELINE = "sim_time"
PLAY_STATE_PAUSED = 1


def _varint(n: int) -> bytes:
    n &= (1 << 64) - 1  # int64 as protobuf writes it (two's complement, 10 bytes when negative)
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _field(number: int, payload: bytes | int) -> bytes:
    """One protobuf field: a varint (int) or length-delimited bytes."""
    if isinstance(payload, int):
        return _varint(number << 3) + _varint(payload)
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def set_time_request(seconds: float, timeline: str = TIMELINE) -> bytes:
    """The encoded ViewerControlRequest moving the cursor to ``seconds`` on the duration ``timeline``, paused."""
    cursor = (_field(2, _field(1, timeline.encode())) + _field(3, _field(1, round(seconds * 1e9)))
              + _field(5, PLAY_STATE_PAUSED))
    return _field(6, cursor)


def seek_native(port: int, seconds: float, timeout_s: float = 120.0, timeline: str = TIMELINE) -> bool:
    """Move the native viewer's cursor (its gRPC server on 127.0.0.1:``port``) to ``seconds``, paused, once its
    recording's ``timeline`` reaches that time (polled; the file loads in the background). False if the viewer
    did not answer or never got there within ``timeout_s``."""
    from rerun.experimental import ViewerClient

    end = time.monotonic() + timeout_s
    target = round(seconds * 1e9)
    while time.monotonic() < end:
        try:
            client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            state = client.get_state()
            reached = any(t.name == timeline and t.end is not None and t.end >= target
                          for rec in state.recordings for t in rec.timelines)
            if reached:
                client.set_time(timeline, duration=seconds, play_state="paused")
                return True
        except (ConnectionError, RuntimeError, OSError):
            pass  # not listening yet
        time.sleep(0.3)
    return False
