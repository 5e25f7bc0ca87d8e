"""Multi-view reconstruction (layer 3): matching across views, 3D poses, the per-frame pipeline.

``matching/`` (paper section 3.2: the cross-view matchers), ``solver/`` (paper section 3.3: the MLE /
MAP solver, its public entry in ``solver/__init__``), ``reconstructors`` (plain DLT triangulation as a
stage), ``pipeline`` (MultiViewPipeline: matching -> reconstruction -> tracking per frame),
``precompile`` (compiles every numba kernel once, with a notice). Cameras, calibration and the DLT live in
``data.geometry``. May import ``data`` (layers 1-2) and the other stages (``models``, ``tracking``);
never ``evaluation`` or the entry points.
"""
