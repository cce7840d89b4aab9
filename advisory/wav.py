"""16-bit PCM WAV output for the renderer and the player's capture of what it played."""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np

from seesys.core.errors import SeesysError


def to_pcm16(samples: np.ndarray) -> bytes:
    """Float samples in [-1, 1] as little-endian int16 bytes (clipped)."""
    return (np.clip(samples, -1.0, 1.0) * 32767.0).round().astype("<i2").tobytes()


class WavWriter:
    """A mono 16-bit WAV written block by block (the header's length is completed on close)."""

    def __init__(self, path: Path, sample_rate: int):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._wav = wave.open(str(path), "wb")
        except OSError as e:
            raise SeesysError(f"cannot write the WAV file {path}: {e}") from None
        self._wav.setnchannels(1)
        self._wav.setsampwidth(2)
        self._wav.setframerate(sample_rate)

    def write(self, samples: np.ndarray) -> None:
        self._wav.writeframes(to_pcm16(samples))

    def close(self) -> None:
        self._wav.close()


def read_wav(path: Path) -> tuple[np.ndarray, int]:
    """A mono 16-bit WAV as float samples in [-1, 1] and its sample rate."""
    with wave.open(str(path), "rb") as w:
        if w.getsampwidth() != 2 or w.getnchannels() != 1:
            raise SeesysError(f"{path}: expected a mono 16-bit WAV")
        data = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
        return data.astype(np.float32) / 32767.0, w.getframerate()
