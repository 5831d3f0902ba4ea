"""pxr-layers: render a USD shot once, keep an index of every light path, cut layers from it.

The package is split by stage of the flow (see ARCHITECTURE.md): ``stage`` reads USD into
plain data (:mod:`pxr_layers.scene`), ``trace`` path-traces it with Embree, ``layers``
writes images.
"""

__version__ = "0.1.0"
