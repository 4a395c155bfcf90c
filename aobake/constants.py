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
