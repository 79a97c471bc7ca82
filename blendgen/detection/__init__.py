"""Object detection shared by the stages: the YOLOX detector (the frame analysis finds real road
users with it, train-check fine-tunes it, the realism score runs it) and COCO-style metrics."""
