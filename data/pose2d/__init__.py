"""2D training data (layer 2): records, COCO files, crops, augmentation, Dataset, synthetic images, COCO AP/AR."""
