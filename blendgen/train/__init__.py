"""The training check: fine-tune the bundled COCO detector (YOLOX-Nano, rebuilt in PyTorch) on
a dataset and score it on real labelled photos. torch is an optional extra (`blendgen[train]`):
only yolox.py, loss.py and check.py's training functions import it, when they run."""
