"""The 2D stage (layer 3; paper section 3.1): network, heatmaps, grouping of joints into persons.

``resnet``, ``fastpose`` (the SPPE network), ``heatmap_codec`` (multi-modal heatmap targets and
decoding), ``loss``, ``candidates`` (joint candidates), ``joint_association`` (global joint
association), ``paf_grouping`` (OpenPose part-affinity grouping), ``training``, ``resume``,
``checkpoint_io``, ``show_targets`` (pictures of the training targets; a CLI).
May import ``data`` (layers 1-2) and the other stages; never ``evaluation`` or the entry points.
"""
