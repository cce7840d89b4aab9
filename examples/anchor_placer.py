"""An AR anchor placer that adapts to SEESys's pose-error estimates (docs/client.md).

An AR app anchors virtual content to the world at the camera's current pose. Anchored while the pose is off, the
content stays off, so this placer defers each placement while Equation 2's class of the latest estimate is at or
above ``--defer-class`` (2: 8 mm and more with the paper's thresholds) or the estimate is older than
``--max-age-s``, and places it as soon as a good estimate arrives. It prints one line per estimate and exits after
placing ``--anchors`` anchors (or after ``--timeout-s`` without an estimate: exit status 1).

    python examples/anchor_placer.py --device device-0 --anchors 3

Start it beside a running service (``seesys estimator serve``) and a device (``seesys monitor run --stream``, or
``seesys run``); endpoint and keys come from configs/network.toml, the thresholds from configs/advisory.toml.
"""

from __future__ import annotations

import argparse
import sys

from seesys.client import EstimateClient, EstimateRecord


class AnchorPlacer:
    """Places ``wanted`` anchors, each at the first estimate good and fresh enough."""

    def __init__(self, wanted: int, defer_class: int, max_age_s: float):
        self.wanted = wanted
        self.defer_class = defer_class
        self.max_age_s = max_age_s
        self.placed: list[int] = []

    def on_estimate(self, record: EstimateRecord) -> str:
        """What the placer did with this estimate: ``deferred`` or ``placed anchor N``."""
        if record.error_class >= self.defer_class or record.age_s > self.max_age_s:
            return "deferred"
        self.placed.append(record.frame_index)
        return f"placed anchor {len(self.placed)}"

    @property
    def done(self) -> bool:
        return len(self.placed) >= self.wanted


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", required=True, help="the device id (its --device-id, or device_id of monitor.toml)")
    parser.add_argument("--anchors", type=int, default=3, help="anchors to place before exiting")
    parser.add_argument("--defer-class", type=int, default=2, help="defer while Equation 2's class is at least this")
    parser.add_argument("--max-age-s", type=float, default=0.5, help="defer on an estimate older than this")
    parser.add_argument("--timeout-s", type=float, default=None, help="give up after this long without an estimate")
    args = parser.parse_args()
    placer = AnchorPlacer(args.anchors, args.defer_class, args.max_age_s)
    with EstimateClient(args.device) as client:
        print(f"listening for {args.device} on {client.endpoint}", flush=True)
        while not placer.done:
            record = client.receive(args.timeout_s)
            if record is None:
                print(f"no estimate for {args.timeout_s} s", flush=True)
                return 1
            action = placer.on_estimate(record)
            print(
                f"frame {record.frame_index} error {record.error_m * 1000:.3f} mm class {record.error_class} "
                f"model {record.model_version}: {action}",
                flush=True,
            )
    print(f"placed {len(placer.placed)} anchors at frames {placer.placed}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
