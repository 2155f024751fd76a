"""A MaterialX gonioreflectometer: a material of a ``.mtlx`` document rendered by MaterialX's own
GLSL shader generator at given direction pairs (issue 42).

:func:`measure_in_materialx` generates the GLSL of a material's surface shader with MaterialX's
``GlslShaderGenerator`` (the ``materialx`` package, 1.39) and runs it on an OpenGL 4 context
without a window (``moderngl`` on EGL: Mesa's llvmpipe where there is no GPU), one point per
direction pair into a float32 target. What it returns is what the generated pixel shader writes
for one directional light of colour 1 and intensity 1 from ``wi``, seen from ``wo``, with no
environment light: ``f(wi, wo) cos(theta_i)`` per RGB channel, linear (no sRGB encoding, no
colour transform; the shader's light loop adds ``intensity x bsdf.response``, and every BSDF
node's response carries the light's cosine). This is the check that an OpenPBR export reflects
what the fitted model reflects (``tests/convert/test_materialx.py``).

Generator options: the complete shader interface (the node's inputs are uniforms), no specular
environment (``hwSpecularEnvironmentMethod`` NONE), no transparency, shadow map or ambient
occlusion, no sRGB output, at most one light (``<directional_light>`` bound as light type 1);
the directional albedo is the generator's default, analytic (``DIRECTIONAL_ALBEDO_METHOD 0``,
checked). Two edits make the generated code run here: ``gl_Position`` comes from a per-point
pixel attribute instead of the view-projection transform (the geometry carries the directions),
and ``u_refractionTwoSided``, which ``lib/mx_transmission_refract.glsl`` reads but MaterialX
1.39.5 leaves undeclared without a specular environment, is declared false (it only scales the
environment's radiance, which is 0 here).

Geometry: the light's direction is a uniform, so each pair is turned by a rotation ``R`` with
``R wi = +z``: per point the normal is ``R z``, the tangent ``R x`` (so an anisotropic lobe's
``x`` is the tangent) and the position ``-R wo`` seen from the origin; the shader's dot products
are those of the local frame up to float32 rounding.

Rounding of the renderer: llvmpipe's ``acos`` is a polynomial approximation, off by up to
1.6e-4 absolute (measured here over [0, 1]; :func:`glsl_error`), which the rough diffuse lobe's
albedo reads; its ``pow`` is within 1.6e-6 relative and ``sqrt`` within 6e-8.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["RENDER_EXTRA", "MaterialXRenderUnavailable", "glsl_error", "measure_in_materialx",
           "shader_sources"]

#: what rendering needs (the message of :class:`MaterialXRenderUnavailable`)
RENDER_EXTRA = ("pip install 'brdf_fit[materialx]' (materialx 1.39 and moderngl) and an OpenGL "
                "4 driver reachable through EGL (Mesa's llvmpipe does without a GPU)")
_GL_POSITION = "gl_Position = u_viewProjectionMatrix * hPositionWorld;"
_PRIVATE_UNIFORMS = "// Uniform block: PrivateUniforms\n"


class MaterialXRenderUnavailable(RuntimeError):
    """MaterialX, moderngl or an EGL OpenGL context is missing."""


def _libraries():
    """MaterialX's standard libraries (:func:`brdf_fit.convert.materialx.standard_libraries`,
    loaded once), missing MaterialX reported as :class:`MaterialXRenderUnavailable`."""
    from brdf_fit.convert.materialx import MaterialXNotFound, standard_libraries

    try:
        return standard_libraries()
    except MaterialXNotFound:
        raise MaterialXRenderUnavailable(f"MaterialX is not installed: {RENDER_EXTRA}") from None


@functools.cache
def _context():
    try:
        import moderngl
    except ImportError:
        raise MaterialXRenderUnavailable(f"moderngl is not installed: {RENDER_EXTRA}") from None
    try:
        return moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # no libEGL, no driver: the library says which
        raise MaterialXRenderUnavailable(f"no OpenGL context through EGL ({exc}): "
                                         f"{RENDER_EXTRA}") from None


def shader_sources(document: str, material: str) -> tuple[str, str]:
    """``(vertex, pixel)`` GLSL of ``material``'s surface shader in the MaterialX ``document``
    (text), as MaterialX's GLSL generator writes them with the options of the module
    docstring, before this module's two edits."""
    import MaterialX as mx
    import MaterialX.PyMaterialXGenGlsl as mx_glsl
    import MaterialX.PyMaterialXGenShader as mx_gen

    lib = _libraries()
    doc = mx.createDocument()
    mx.readFromXmlString(doc, document)
    doc.importLibrary(lib)
    node = doc.getNode(material)
    if node is None or node.getCategory() != "surfacematerial":
        names = [n.getName() for n in doc.getNodes() if n.getCategory() == "surfacematerial"]
        raise ValueError(f"no surfacematerial {material!r} in the document; it has: "
                         f"{', '.join(names) or 'none'}")
    shaders = mx.getShaderNodes(node)
    if len(shaders) != 1:
        raise ValueError(f"{material}: expected one surface shader, found {len(shaders)}")
    gen = mx_glsl.GlslShaderGenerator.create()
    ctx = mx_gen.GenContext(gen)
    ctx.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    o = ctx.getOptions()
    o.shaderInterfaceType = mx_gen.ShaderInterfaceType.SHADER_INTERFACE_COMPLETE
    o.hwSpecularEnvironmentMethod = mx_gen.HwSpecularEnvironmentMethod.SPECULAR_ENVIRONMENT_NONE
    o.hwTransparency = False
    o.hwSrgbEncodeOutput = False
    o.emitColorTransforms = False
    o.hwShadowMap = False
    o.hwAmbientOcclusion = False
    o.hwWriteAlbedoTable = False
    o.hwWriteEnvPrefilter = False
    o.hwMaxActiveLightSources = 1
    mx_gen.HwShaderGenerator.bindLightShader(doc.getNodeDef("ND_directional_light"), 1, ctx)
    shader = gen.generate("brdf_fit_gonio", shaders[0], ctx)
    vs = shader.getSourceCode(mx_gen.VERTEX_STAGE)
    ps = shader.getSourceCode(mx_gen.PIXEL_STAGE)
    if "#define DIRECTIONAL_ALBEDO_METHOD 0" not in ps:
        raise RuntimeError("MaterialX's generator did not choose the analytic directional "
                           "albedo; this module's parity was measured with it")
    return vs, ps


@functools.lru_cache(maxsize=16)
def _program(document: str, material: str):
    vs, ps = shader_sources(document, material)
    if vs.count(_GL_POSITION) != 1 or "in vec3 i_position;" not in vs:
        raise RuntimeError("MaterialX's vertex shader changed: gl_Position is not written "
                           "where this module expects")
    vs = vs.replace(_GL_POSITION, "gl_Position = vec4(i_pixel, 0.0, 1.0);")
    vs = vs.replace("in vec3 i_position;", "in vec3 i_position;\nin vec2 i_pixel;", 1)
    if "u_refractionTwoSided" in ps and "uniform bool u_refractionTwoSided" not in ps:
        ps = ps.replace(_PRIVATE_UNIFORMS,
                        _PRIVATE_UNIFORMS + "uniform bool u_refractionTwoSided = false;\n", 1)
    return _context().program(vertex_shader=vs, fragment_shader=ps)


def _frame_with_first_axis(a):
    """Right-handed orthonormal frames (columns) whose first column is ``a`` (unit)."""
    helper = np.where(np.abs(a[:, :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    b = np.cross(a, helper)
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    return np.stack([a, b, np.cross(a, b)], axis=-1)


def _set(prog, name, value):
    if name in prog:  # the compiler drops the uniforms it does not read
        prog[name].value = value


def measure_in_materialx(document: str, material: str, wi, wo, width: int = 1024,
                         spin: float = 0.0) -> np.ndarray:
    """``(N, 3)`` float32: ``f(wi, wo) cos(theta_i)`` of ``material`` in the MaterialX
    ``document`` (text) as MaterialX's generated GLSL computes it (module docstring), at unit
    directions ``wi`` (toward the light) and ``wo`` (toward the viewer), ``(N, 3)`` in the
    surface's frame (normal +z, tangent +x). ``spin`` turns the world frame about the light
    (radians): the same value up to the shader's float32 rounding, which differs from spin to
    spin, so that a few spins measure the renderer's own rounding at each pair (large where a
    value is ill-conditioned: a narrow lobe at grazing near-mirror pairs, whose half vector is
    a difference of nearly opposite directions). :class:`MaterialXRenderUnavailable` without
    MaterialX, moderngl or an EGL context."""
    import moderngl

    prog = _program(document, material)
    gl = _context()
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    wo = np.asarray(wo, np.float64).reshape(-1, 3)
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
    wi = wi / np.linalg.norm(wi, axis=1, keepdims=True)
    wo = wo / np.linalg.norm(wo, axis=1, keepdims=True)
    n = len(wi)
    _set(prog, "u_numActiveLightSources", 1)
    _set(prog, "u_lightData[0].type", 1)
    _set(prog, "u_lightData[0].color", (1.0, 1.0, 1.0))
    _set(prog, "u_lightData[0].intensity", 1.0)
    _set(prog, "u_lightData[0].direction", (0.0, 0.0, -1.0))  # travelling down: L = +z
    _set(prog, "u_viewPosition", (0.0, 0.0, 0.0))
    # R maps wi to +z: R = F(+z) F(wi)^T with F(a) a frame whose first axis is a
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    c, s = np.cos(spin), np.sin(spin)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rot = turn @ _frame_with_first_axis(up) @ np.swapaxes(_frame_with_first_axis(wi), 1, 2)
    w = min(n, width)
    h = -(-n // w)
    k = np.arange(n)
    pixel = np.stack([2.0 * (k % w + 0.5) / w - 1.0, 2.0 * (k // w + 0.5) / h - 1.0], 1)
    vertices = np.concatenate([-np.einsum("nij,nj->ni", rot, wo), rot[:, :, 2], rot[:, :, 0],
                               pixel], 1).astype("f4")
    vbo = gl.buffer(vertices.tobytes())
    vao = gl.vertex_array(prog, [(vbo, "3f 3f 3f 2f", "i_position", "i_normal", "i_tangent",
                                  "i_pixel")])
    target = gl.texture((w, h), 4, dtype="f4")
    fbo = gl.framebuffer(color_attachments=[target])
    try:
        fbo.use()
        gl.viewport = (0, 0, w, h)
        gl.disable(moderngl.DEPTH_TEST | moderngl.BLEND | moderngl.CULL_FACE)
        gl.point_size = 1.0
        fbo.clear(-1.0, -1.0, -1.0, -1.0)
        vao.render(mode=moderngl.POINTS, vertices=n)
        image = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
    finally:
        for obj in (vao, vbo, target, fbo):
            obj.release()
    out = image.reshape(-1, 4)[:n]
    if not np.all(out[:, 3] == 1.0):
        raise RuntimeError(f"{int(np.sum(out[:, 3] != 1.0))} of {n} points were not drawn")
    return out[:, :3].copy()


def glsl_error(function: str, lo: float, hi: float, exact, n: int = 4096,
               relative: bool = False) -> float:
    """The largest error of the GLSL ``function`` (a name: ``"acos"``) on this context's
    driver over ``n`` points of ``[lo, hi]`` against ``exact`` (a NumPy function), absolute or
    relative: how far the renderer's own arithmetic is from exact (module docstring)."""
    gl = _context()
    prog = gl.program(
        vertex_shader="#version 330\nin vec2 p;\nvoid main() { gl_Position = vec4(p, 0.0, 1.0); }",
        fragment_shader=("#version 330\nuniform float lo;\nuniform float hi;\nout vec4 o;\n"
                         f"void main() {{ float x = lo + (hi - lo) * (gl_FragCoord.x - 0.5) / "
                         f"{n - 1}.0; o = vec4({function}(x), x, 0.0, 1.0); }}"))
    prog["lo"].value, prog["hi"].value = float(lo), float(hi)
    vbo = gl.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = gl.vertex_array(prog, [(vbo, "2f", "p")])
    target = gl.texture((n, 1), 4, dtype="f4")
    fbo = gl.framebuffer(color_attachments=[target])
    try:
        fbo.use()
        gl.viewport = (0, 0, n, 1)
        vao.render()
        r = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(-1, 4)
    finally:
        for obj in (vao, vbo, target, fbo, prog):
            obj.release()
    x, y = r[:, 1].astype(np.float64), r[:, 0].astype(np.float64)
    err = np.abs(y - exact(x))
    if relative:
        err = err / np.maximum(np.abs(exact(x)), np.finfo(np.float64).tiny)
    return float(err.max())
