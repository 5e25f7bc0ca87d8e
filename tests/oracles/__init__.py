"""Frozen reference implementations the tests compare the package against (test oracles, not package code)."""
