"""Choosing and opening the audio output with ``sounddevice``, with clear errors when there is none.

PortAudio scans the devices once, when ``sounddevice`` is imported, so the import happens here, in the player
process, and not at module level elsewhere (an audio server started later would not be seen).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from advisory.config import AudioConfig
from seesys.core.errors import SeesysError


class AudioDeviceError(SeesysError):
    """No usable audio output: none at all, not the configured one, or it refuses the stream's settings."""


@dataclass(frozen=True)
class OutputDevice:
    index: int
    name: str
    host_api: str


def _sounddevice():
    try:
        import sounddevice
    except OSError as e:  # libportaudio2 missing
        raise AudioDeviceError(f"cannot load PortAudio: {e} (install libportaudio2)") from None
    return sounddevice


def find_output_device(audio: AudioConfig) -> OutputDevice:
    """The output device the configuration names (or the default one); AudioDeviceError when there is none."""
    sd = _sounddevice()
    host_apis = sd.query_hostapis()
    devices = sd.query_devices()
    api = None
    if audio.host_api:
        matches = [i for i, h in enumerate(host_apis) if h["name"].lower().startswith(audio.host_api.lower())]
        if not matches:
            names = ", ".join(h["name"] for h in host_apis) or "none"
            raise AudioDeviceError(f"audio host API {audio.host_api!r} not found (available: {names})")
        api = matches[0]
    outputs = [
        i
        for i, d in enumerate(devices)
        if d["max_output_channels"] >= audio.channels and (api is None or d["hostapi"] == api)
    ]
    where = f" in host API {host_apis[api]['name']!r}" if api is not None else ""
    if not outputs:
        raise AudioDeviceError(
            f"no audio output device with {audio.channels} channel(s){where}: connect a sound "
            f"card or start an audio server (e.g. JACK)"
        )
    if audio.output_device:
        named = [i for i in outputs if audio.output_device.lower() in devices[i]["name"].lower()]
        exact = [i for i in named if devices[i]["name"].lower() == audio.output_device.lower()]
        if len(exact) == 1:
            named = exact
        if len(named) != 1:
            names = ", ".join(repr(devices[i]["name"]) for i in outputs)
            problem = "not found" if not named else "is ambiguous"
            raise AudioDeviceError(f"audio output device {audio.output_device!r} {problem}{where} (outputs: {names})")
        index = named[0]
    else:
        default = host_apis[api]["default_output_device"] if api is not None else sd.default.device[1]
        index = default if default in outputs else outputs[0]
    return OutputDevice(index, devices[index]["name"], host_apis[devices[index]["hostapi"]]["name"])


def open_output_stream(audio: AudioConfig, device: OutputDevice, callback: Callable):
    """An unstarted float32 ``sd.OutputStream`` on ``device``; AudioDeviceError if PortAudio refuses it."""
    sd = _sounddevice()
    try:
        return sd.OutputStream(
            device=device.index,
            samplerate=audio.sample_rate,
            channels=audio.channels,
            blocksize=audio.blocksize,
            dtype="float32",
            latency="low",
            callback=callback,
        )
    except sd.PortAudioError as e:
        raise AudioDeviceError(
            f"cannot open audio output {device.name!r} ({device.host_api}) at {audio.sample_rate} Hz: {e}"
        ) from None


def check_output_device(audio: AudioConfig) -> OutputDevice:
    """:func:`find_output_device` for a process that will not play (the supervisor): PortAudio is shut down again
    at once, while its audio server is surely alive, so that this process cannot hang at exit in ``Pa_Terminate``
    if the server dies later."""
    try:
        return find_output_device(audio)
    finally:
        sd = _sounddevice()
        sd._terminate()
