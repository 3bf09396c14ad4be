"""Core: geometry, warping, metrics, errors, names, options and output safety; imports nothing else from sparself."""
