"""File formats (layer 1): readers and writers, one module per format; imports only layer 1 and third parties."""
