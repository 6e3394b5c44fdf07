"""Test helpers shared by several test packages (importable as ``helpers`` from any test module)."""
