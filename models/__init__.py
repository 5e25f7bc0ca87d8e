"""The 2D stage (layer 3; paper section 3.1): network, heatmaps, grouping of joints into persons.

``resnet`` (torchvision's ResNet trunk, optional squeeze-excitation), ``fastpose`` (the SPPE network),
``heatmap_codec`` (multi-modal heatmap targets and decoding), ``loss``, ``candidates`` (joint candidates),
``joint_association`` (global joint association), ``paf_grouping`` (OpenPose part-affinity grouping),
``training``, ``resume``, ``checkpoint_io``, ``show_targets`` (pictures of the training targets; a CLI),
``detectors`` (person boxes: ground truth, a COCO detections file, a torchvision detector),
``keypointrcnn`` (torchvision's Keypoint R-CNN as a baseline 2D source), ``tv_detection`` (torchvision
detection models by name, run on BGR images), ``tv_weights`` (pretrained weights: torchvision's weights
API or a local file; offline, one line).
May import ``data`` (layers 1-2) and the other stages; never ``evaluation`` or the entry points.
"""
