"""Where the advisory's sound goes, for a supervisor that starts the player (``seesys run``, ``seesys study run``):
the configured output device (``configs/advisory.toml`` ``[audio]``; the default one unless named), or, on a
machine without one (or when asked), a private JACK dummy server started here (``advisory.sandbox.JackDummy``),
paced in real time like a sound card and heard by nobody.

The children then run with the audio settings of :meth:`AudioOutput.settings` in their copy of the configs
(``seesys.io.config.ConfigSet``) and :meth:`AudioOutput.env` in their environment; :meth:`AudioOutput.stop` stops the
server once the player has stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from advisory.config import AudioConfig
from advisory.sandbox import JACK_HOST_API, JackDummy
from seesys.core.errors import SeesysError


@dataclass
class AudioOutput:
    description: str  # for the operator and the run's record
    jack: JackDummy | None = None
    unavailable: str | None = None  # why the configured output device was not used (None: it was, or not asked)

    def settings(self, audio: AudioConfig) -> AudioConfig:
        """The audio settings the children run with: ``audio``, or the JACK server's host API where it plays."""
        return audio if self.jack is None else replace(audio, host_api=JACK_HOST_API, output_device="")

    def env(self) -> dict[str, str]:
        return self.jack.env() if self.jack is not None else {}

    def stop(self) -> None:
        if self.jack is not None:
            self.jack.stop()


def open_audio_output(audio: AudioConfig, dummy: bool = False) -> AudioOutput:
    """The configured output device when it can be used and ``dummy`` is false; otherwise a JACK dummy server,
    started. SeesysError when there is no output device and jackd is not installed, or the server does not start."""
    unavailable = None
    if not dummy:
        from advisory.audio_device import AudioDeviceError, check_output_device

        try:
            device = check_output_device(audio)
            return AudioOutput(f"output device {device.name!r} ({device.host_api})")
        except AudioDeviceError as e:
            unavailable = str(e)
    if not JackDummy.available():
        raise SeesysError(
            f"{unavailable or 'no sound card asked for'}, and jackd is not installed to stand in for a "
            f"sound card (apt package jackd2); or run the silent condition (none)"
        )
    jack = JackDummy(audio.sample_rate, audio.blocksize)
    jack.start()
    return AudioOutput(f"JACK dummy server {jack.name}, no sound card used", jack, unavailable)
