"""The path index: events of every light path, written while rendering, read to cut layers."""
