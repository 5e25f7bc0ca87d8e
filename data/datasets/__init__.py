"""Multi-view datasets (layer 2): one loader per ``configs/dataset/*.yaml`` ``_target_``, each returning a Sequence."""
