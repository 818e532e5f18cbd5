"""The image pipeline: frames in, calibrated reflectance samples out.

Modules: ``target`` (board/patch layout, camera model and pose), ``markers`` (ChArUco pose),
``dark`` (dark-frame cache), ``exposure`` (bracket choice), ``hdr`` (frame checks, linear HDR merge,
8-bit response recovery), ``reflectance`` (per-pixel geometry, white reference, binning to samples),
``acquire`` (:class:`~gonio.pipeline.acquire.Pipeline`: one pose end to end).
Nothing is imported here, so ``import gonio.pipeline`` stays cheap.
"""
