"""Pictures of a run: frame pictures, drawing primitives, plots, trajectories and the sequence viewer."""
