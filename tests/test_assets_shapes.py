"""Vehicle shapes without Blender (assets_procedural/shapes.py on a MeshBuilder)."""

import numpy as np

from assets_procedural.meshkit import MeshBuilder
from assets_procedural.shapes import BUILDERS
from blendgen.scene.catalog import sample_variant
from test_assets_body import _regions


def test_bus_rear_is_a_window_over_a_panel_and_louvres():
    """Seen from behind (most dashcam views of a bus), one window over the whole back read as a
    flat toy panel on the real highway photos: the rear window keeps to the upper third, the
    engine hatch's louvres sit below it, tall lamp clusters at the corners."""
    rng = np.random.default_rng(2)
    for _ in range(4):
        v, (L, W, H) = sample_variant("bus", rng)
        mb = MeshBuilder()
        BUILDERS["bus"](mb, v, L, W, H)
        rear = -L / 2 + 0.05
        parts = _regions(mb)
        glass = parts["glass"]
        back = glass[glass[:, 0] < rear]
        assert len(back) and back[:, 2].min() > 0.6 * H and back[:, 2].max() < 0.9 * H
        plastic = parts["plastic"]
        louvres = plastic[(plastic[:, 0] < rear) & (plastic[:, 2] > 0.6) & (plastic[:, 2] < 0.5 * H)]
        assert len(np.unique(np.round(louvres[:, 2], 3))) >= 12  # six slats, top and bottom faces
        lamps = parts["lamp_tail"]
        assert np.ptp(lamps[lamps[:, 0] < rear][:, 2]) >= 0.45
