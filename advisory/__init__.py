"""The audio error advisory: Equation 2 and the rotation rule, the generator and player processes, and the
WAV renderer.

Modules, from the rules to the processes (see docs/advisory.md):

- ``config``: ``configs/advisory.toml`` as typed dataclasses.
- ``pulses``: Equation 2 and the rotation rule (exact at the thresholds); ``synth``: one buffer of N pulses.
- ``rotation``: angular speed from the device's feature stream; ``conditions``: seesys / rotation / none.
- ``scheduler``: moving average, 3 Hz ticks, prompt changes, stale input, with the clock passed in.
- ``generator`` and ``player``: the two processes; ``handoff``: the buffer message between them;
  ``audio_device``: finding and opening the output; ``output``: the sound card or, without one, a JACK dummy
  server, for a supervisor that starts the player; ``supervisor``: ``seesys advisory run``.
- ``render`` (offline WAV), ``replay`` (an estimate log published at its pace), ``estimate_log``, ``logs``,
  ``wav``, ``process``; ``sandbox``: a JACK dummy server and private configs for tests and benchmarks.
"""
