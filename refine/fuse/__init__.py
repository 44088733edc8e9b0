"""The fusion wing: the demonstration matched to the CAD path.

The fusion wing: the demonstration aligned to the CAD path (:mod:`~refine.fuse.align`), in the
worker's direction and from the worker's start (:mod:`~refine.fuse.order`), fused into the path the
optimiser refines (:mod:`~refine.fuse.fusion`), the tracker-frame check on the result
(:mod:`~refine.fuse.frame_check`), and the passes of a multi-layer weld (:mod:`~refine.fuse.passes`).
"""
