"""Multi-view datasets (layer 2): one loader module per dataset, each the ``_target_`` of a
``configs/dataset/*.yaml`` returning a :class:`data.multiview.Sequence`.

``files`` (your own cameras.json + poses2d.json), ``shelf`` (Shelf with 4D Association's detections),
``panoptic`` (CMU Panoptic), ``wildtrack`` (Wildtrack calibrations, synthetic bodies), ``synthetic``
(the built-in synthetic crowd, optionally rendered), ``images`` (your calibration and each camera's frames:
folders, videos or images). A loader lists the inputs of its benchmark protocol in
``Sequence.protocol_inputs``; :func:`evaluation.protocols.attach_protocols` builds the protocols. A stage
a loader needs (the Shelf PAF grouping) is given to it by the config.
May import layers 1 and 2 (``data.*``); never the stages, ``evaluation`` or the entry points.
"""
