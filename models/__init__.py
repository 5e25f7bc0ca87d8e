"""The 2D stage (paper section 3.1): network, heatmaps, grouping of joints into persons; never imports evaluation."""
