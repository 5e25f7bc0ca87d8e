"""2D training data (layer 2) for the 2D network: records, COCO keypoint files, crops and augmentation, the
torch Dataset, synthetic single- and multi-view images, per-view COCO documents and their AP/AR."""
