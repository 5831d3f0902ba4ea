"""Images out: EXR files (and later previews and layer extraction)."""
