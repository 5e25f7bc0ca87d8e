"""Multi-view datasets (layer 2): one module per dataset (files, shelf, panoptic, wildtrack, synthetic), each
a loader ``configs/dataset/*.yaml`` targets that returns a :class:`data.multiview.Sequence`.

May import layer 1 (``data.*``, ``data.formats``, ``data.geometry``) and layer 2 (``data.synthetic``, ``data.pose2d``);
never the stages, evaluation or entry points (protocols are attached in the evaluation layer).
"""
