"""blendgen: real driving recordings in, larger and rarer perfectly labelled training sets out."""

__version__ = "0.1.0"

# The seven object classes and their COCO category ids (DESIGN.md), so COCO-trained
# detectors can be scored on the output directly.
CLASSES: dict[str, int] = {
    "person": 1,
    "bicycle": 2,
    "car": 3,
    "motorcycle": 4,
    "bus": 6,
    "truck": 8,
    "traffic light": 10,
}
