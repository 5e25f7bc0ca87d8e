"""Multi-view datasets (layer 2): one loader per ``configs/dataset/*.yaml`` ``_target_``, each returning a
:class:`data.multiview.Sequence` (files, shelf, panoptic, wildtrack, synthetic, images)."""
