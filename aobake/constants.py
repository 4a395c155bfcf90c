"""Constants every stage shares (named once, as trimesh's ``constants.py``): the axes and
the float32 offset floor.  A leaf module: it imports nothing of aobake's, so the option
records beside their plugins and the stages themselves can all import it."""

#: the axes, as the CLI names them (``--up-axis``)
AXES = ("x", "y", "z")
#: float32 ulps of a point's (rebased) coordinates its origin is lifted at least: Embree's
#: hit distances carry a few ulps of error, so 64 keeps a ray off its own triangle.
OFFSET_ULPS = 64
#: hardware depth-buffer conventions (``aobake.camera.hardware_depth`` / ``linearize_depth``)
DEPTH_CONVENTIONS = ("opengl", "d3d", "reversed")
#: the farthest hit distance a ray is traced to, in the tracer's local frame (float32): a
#: finite stand-in for infinity (Embree's tfar must be finite and below float32's max), far
#: beyond the scene, which the local frame scales into [-1, 1)
RAY_FAR = 1e37
