"""Real road users' sizes per class and body type (metres; length x, width y, height z).

The object catalog (`scene.catalog`) draws its vehicles from the body-type ranges; the frame
analysis (`analysis.objects`) assumes a detected real road user measures its class's typical
size.
"""

from __future__ import annotations

import numpy as np

# kind -> (length range, width range, height range)
CAR_BODIES = {
    "sedan": ((4.40, 4.90), (1.76, 1.86), (1.40, 1.50)),
    "hatchback": ((3.80, 4.25), (1.68, 1.78), (1.42, 1.54)),
    "suv": ((4.50, 4.95), (1.85, 1.98), (1.65, 1.80)),
    "van": ((4.80, 5.30), (1.90, 2.02), (1.72, 2.00)),
}
TRUCK_BODIES = {
    "box_truck": ((6.5, 8.5), (2.40, 2.50), (3.20, 3.60)),
    "semi": ((15.0, 16.5), (2.50, 2.55), (3.80, 4.00)),
    "pickup": ((5.30, 5.90), (1.95, 2.05), (1.80, 1.95)),
}
BUS_BODIES = {
    "city": ((11.5, 12.2), (2.50, 2.55), (3.00, 3.20)),
    "midi": ((8.5, 9.5), (2.35, 2.45), (2.90, 3.05)),
}


def _mid(ranges) -> tuple[float, float, float]:
    return tuple(float(np.mean([np.mean(r[i]) for r in ranges])) for i in range(3))


# Typical (length, width, height) per class: what a real road user found by a detector is
# assumed to measure (the mean of the body-type ranges above; riders included).
TYPICAL_DIMS: dict[str, tuple[float, float, float]] = {
    "car": _mid(CAR_BODIES.values()),
    "truck": _mid(TRUCK_BODIES.values()),
    "bus": _mid(BUS_BODIES.values()),
    "person": (0.45, 0.55, 1.71),
    "bicycle": (1.75, 0.61, 1.65),
    "motorcycle": (2.1, 0.81, 1.55),
}
