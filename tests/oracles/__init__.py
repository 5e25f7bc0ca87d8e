"""Independent implementations the tests compare the package against (not package code)."""
