"""Pictures of a run (layer 4): ``visualize`` (save_run_pictures), ``vis_draw`` (drawing primitives),
``vis_plots`` (plots), ``vis_trajectories``, ``sequence_view`` / ``sequence_html`` / ``sequence_data``
and ``sequence_view.html`` (the interactive sequence viewer page).
May import layers 1-3 and the rest of ``evaluation``; never the entry points.
"""
