"""The player process (paper §7.2, process b): plays the latest buffer through a ``sounddevice`` stream.

A receiver thread takes buffers off the conflating SUB socket and puts the newest in a one-slot hand-off; the audio
callback reads that slot and never waits on anything. A new buffer replaces the one playing, starting at the
sample whose DAC time is the buffer's ``play_at`` (or as soon as possible when that is already past), so the
cadence is exact to the sample and does not depend on the audio block size. When a buffer ends and no new one has
come, the output is silent: a generator that stops leaves no stale advice playing.

``playback.csv`` gets one row per buffer that started, with the DAC time of its first sample (CLOCK_MONOTONIC in
the callback plus the output latency PortAudio reports, ``outputBufferDacTime − currentTime``) and the index of
that sample in the stream's output, which is its position in the capture. ``--capture`` also writes what the
callback wrote to a WAV file, block after block (a cycle the audio server skipped, an xrun, is not in it: the DAC
times in ``playback.csv`` give the timeline).

A stream that stops on its own (device unplugged, audio server gone), or whose callbacks stop coming (a JACK
server that dropped the client), is logged and ends the process with status :data:`DEVICE_LOST_EXIT`; the
supervisor restarts it. PortAudio cannot be closed or re-initialised once its JACK server has died (both calls
hang), so a fresh process is the only clean way back.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import zmq

from advisory.audio_device import find_output_device, open_output_stream
from advisory.config import AdvisoryConfig
from advisory.handoff import AudioBuffer, HandoffError, decode_buffer
from advisory.logs import EventLog
from advisory.wav import WavWriter
from seesys.core.session_layout import PLAYBACK_COLUMNS, PLAYBACK_CSV
from seesys.io.logfiles import CsvLog
from seesys.io.transport import subscriber

DEVICE_LOST_EXIT = 3


class PlaybackState:
    """What the receiver thread and the audio callback share; the callback only reads the one-slot hand-off."""

    def __init__(self, sample_rate: int, capture: bool):
        # (buffer, monotonic time of its receipt), written by the receiver thread only
        self.latest: tuple[AudioBuffer, float] | None = None
        self._rate = sample_rate
        self._current_entry: tuple[AudioBuffer, float] | None = None
        self._current: AudioBuffer | None = None
        self._pos = 0
        self._capture = capture
        # (buffer, its receipt, DAC time of its first sample, index of that sample in the stream's output), one per
        # buffer that started
        self.started: deque[tuple[AudioBuffer, float, float, int]] = deque()
        self._samples_out = 0
        self.blocks: deque[np.ndarray] = deque()  # what the callback wrote, block by block
        self.status_flags: deque[str] = deque()
        self.callbacks = 0

    def _fill(self, out: np.ndarray, start: int, end: int) -> None:
        cur = self._current
        if cur is None or start >= end:
            return
        n = min(end - start, cur.samples.size - self._pos)
        if n > 0:
            out[start : start + n] = cur.samples[self._pos : self._pos + n]
            self._pos += n

    def callback(self, outdata: np.ndarray, frames: int, time_info, status) -> None:
        self.callbacks += 1
        # Now plus the output latency PortAudio reports for this block. Not the stream clock itself: under a loaded
        # JACK dummy server its times jump by tens of milliseconds both ways, while this difference stays put.
        block_dac = time.monotonic() + (time_info.outputBufferDacTime - time_info.currentTime)
        out = outdata[:, 0]
        out.fill(0.0)
        pending = self.latest
        switch_at = frames
        if pending is not None and pending is not self._current_entry:
            switch_at = min(max(int(round((pending[0].play_at - block_dac) * self._rate)), 0), frames)
        self._fill(out, 0, switch_at)
        if pending is not None and switch_at < frames:  # it is earlier than the block's end only for a new buffer
            self._current_entry, self._current, self._pos = pending, pending[0], 0
            self.started.append((*pending, block_dac + switch_at / self._rate, self._samples_out + switch_at))
            self._fill(out, switch_at, frames)
        if outdata.shape[1] > 1:
            outdata[:, 1:] = out[:, None]
        self._samples_out += frames
        if self._capture:
            self.blocks.append(out.copy())
        if status:
            self.status_flags.append(str(status))


class Player:
    """One player: the output stream, the hand-off receiver and the logs."""

    def __init__(self, cfg: AdvisoryConfig, out: Path, capture: Path | None = None):
        self._cfg = cfg
        device = find_output_device(cfg.audio)
        self._state = PlaybackState(cfg.audio.sample_rate, capture is not None)
        self._stream = open_output_stream(cfg.audio, device, self._state.callback)
        self._events = EventLog(out, "player")
        self._log = CsvLog(out / PLAYBACK_CSV, PLAYBACK_COLUMNS)
        self._wav = WavWriter(capture, cfg.audio.sample_rate) if capture else None
        self._ctx = zmq.Context()
        self._sub = subscriber(self._ctx, cfg.handoff.endpoint, "advisory hand-off", [b""], conflate=True)
        self._receiver_notes: deque[tuple[str, str]] = deque()
        self._device = device

    def _receive(self, stop: threading.Event) -> None:
        poll_ms = self._cfg.handoff.poll_ms
        while not stop.is_set():
            if not self._sub.poll(poll_ms):
                continue
            body = self._sub.recv()
            try:
                buf = decode_buffer(body)
            except HandoffError as e:
                self._receiver_notes.append(("bad buffer", str(e)))
                continue
            if buf.sample_rate != self._cfg.audio.sample_rate:
                self._receiver_notes.append(
                    (
                        "bad buffer",
                        f"sample rate {buf.sample_rate} Hz, the stream runs at {self._cfg.audio.sample_rate} Hz",
                    )
                )
                continue
            self._state.latest = (buf, time.monotonic())

    def _drain(self) -> None:
        """Write what the callback and the receiver left: playback rows, captured audio, notes."""
        state = self._state
        while state.started:
            buf, received, dac, sample = state.started.popleft()
            self._log.write(
                time.time(),
                buf.buffer_id,
                buf.time,
                buf.trigger,
                buf.n_pulses,
                buf.played_pulses,
                buf.arrival,
                received,
                buf.play_at,
                dac,
                sample,
            )
        while state.blocks and self._wav is not None:
            self._wav.write(state.blocks.popleft())
        flags = []
        while state.status_flags:
            flags.append(state.status_flags.popleft())
        if flags:
            self._events.event("stream status", f"{len(flags)} callback(s) flagged: {', '.join(sorted(set(flags)))}")
        while self._receiver_notes:
            self._events.event(*self._receiver_notes.popleft())

    def run(self, stop: threading.Event) -> None:
        """Play until ``stop`` is set; if the stream dies or stalls, log it and end the process (see module doc)."""
        receiver_stop = threading.Event()
        receiver = threading.Thread(target=self._receive, args=(receiver_stop,), name="handoff-receiver", daemon=True)
        receiver.start()
        self._stream.start()
        self._events.event(
            "started",
            f"device={self._device.name!r} ({self._device.host_api}) "
            f"rate={self._cfg.audio.sample_rate} latency={self._stream.latency:.4f}s "
            f"handoff={self._cfg.handoff.endpoint}",
        )
        poll_s = self._cfg.handoff.poll_ms / 1000.0
        callbacks, last_callback = self._state.callbacks, time.monotonic()
        while not stop.wait(poll_s):
            self._drain()
            now = time.monotonic()
            if self._state.callbacks != callbacks:
                callbacks, last_callback = self._state.callbacks, now
            stalled = now - last_callback > self._cfg.audio.stall_after_s
            if not self._stream.active or stalled:
                why = f"no callback for {now - last_callback:.1f} s" if stalled else "the stream stopped"
                self._events.event("audio device lost", f"{self._device.name!r}: {why}")
                self._close_files()
                os._exit(DEVICE_LOST_EXIT)  # a normal exit would hang in Pa_Terminate (see the module doc)
        receiver_stop.set()
        receiver.join()
        self._stream.stop()
        self._stream.close()
        self._drain()
        self._events.event("stopped")
        self._sub.close()
        self._ctx.term()
        self._close_files()

    def _close_files(self) -> None:
        self._log.close()
        self._events.close()
        if self._wav is not None:
            self._wav.close()
