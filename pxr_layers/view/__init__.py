"""The layer inspector: ``pxr-layers view PATH``, a local web application over one render's
products and path index (session.py: the state; inspect.py: what a selection is made of;
composite.py: the regrade rule; server.py: HTTP; static/: the page)."""
