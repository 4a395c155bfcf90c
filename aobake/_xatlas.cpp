/* aobake._xatlas: xatlas's charting, built from third_party/xatlas (speed patches, the same
 * charts: see third_party/xatlas/README.md), for aobake.targets.texels.unwrap.
 *
 * One function, the one call aobake makes of the xatlas package (xatlas-python):
 *
 *   chart(meshes, max_chart_area, texels_per_unit, charts_only=False)
 *       meshes: sequence of (positions, vertex_count, indices, face_count); positions a
 *       C-contiguous buffer of vertex_count * 3 float32, indices of face_count * 3 uint32.
 *       Charts every mesh (ChartOptions defaults but maxChartArea) and packs them with
 *       padding 0, no bilinear margin, at texels_per_unit (PackOptions defaults otherwise).
 *   -> (width, height, [(vmapping, indices, uv) per mesh]) with bytes holding
 *       vmapping (k,) uint32 (xref), indices (face_count, 3) uint32 and uv (k, 2) float32
 *       divided by the atlas's width and height, exactly as xatlas-python's Atlas[i] returns
 *       them, so the two give the same bits.
 *   charts_only: PackOptions::aobakeChartsOnly (third_party/xatlas/README.md): each chart
 *       transformed as packing does, but placed nowhere (no search for a place, xatlas's
 *       one serial step); the uv are then in texels (not divided) and width = height = 1.
 *       The same vmapping and indices; each chart's uv are the packed ones but for the
 *       chart's translation (and a swap of its axes where packing turned it).
 *
 * The GIL is released while xatlas runs (on its own threads).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cstdint>
#include <cstring>

#include "xatlas.h"

namespace {

struct Buffers {
    Py_buffer positions{}, indices{};
    bool have_positions = false, have_indices = false;
    ~Buffers()
    {
        if (have_positions) PyBuffer_Release(&positions);
        if (have_indices) PyBuffer_Release(&indices);
    }
};

struct AtlasHandle {
    xatlas::Atlas *atlas = xatlas::Create();
    ~AtlasHandle() { xatlas::Destroy(atlas); }
};

int take(PyObject *object, Py_buffer *view, bool *have, const char *name, Py_ssize_t itemsize,
         Py_ssize_t count)
{
    if (PyObject_GetBuffer(object, view, PyBUF_C_CONTIGUOUS) < 0) return -1;
    *have = true;
    if (view->len != itemsize * count) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd bytes, got %zd", name,
                     itemsize * count, view->len);
        return -1;
    }
    return 0;
}

PyObject *chart(PyObject *, PyObject *args)
{
    PyObject *meshes;
    float max_chart_area, texels_per_unit;
    int charts_only = 0;
    if (!PyArg_ParseTuple(args, "Off|p", &meshes, &max_chart_area, &texels_per_unit,
                          &charts_only))
        return nullptr;
    PyObject *seq = PySequence_Fast(meshes, "meshes must be a sequence");
    if (!seq) return nullptr;
    const Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    Buffers *buffers = new Buffers[n > 0 ? n : 1];
    AtlasHandle handle;
    PyObject *result = nullptr;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *positions, *indices;
        Py_ssize_t vertex_count, face_count;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "OnOn;a mesh is (positions, "
                              "vertex_count, indices, face_count)", &positions, &vertex_count,
                              &indices, &face_count))
            goto done;
        if (vertex_count < 0 || face_count < 0 || vertex_count > UINT32_MAX ||
            face_count > UINT32_MAX / 3) {
            PyErr_SetString(PyExc_ValueError, "vertex or face count out of range");
            goto done;
        }
        if (take(positions, &buffers[i].positions, &buffers[i].have_positions, "positions",
                 3 * sizeof(float), vertex_count) < 0 ||
            take(indices, &buffers[i].indices, &buffers[i].have_indices, "indices",
                 3 * sizeof(uint32_t), face_count) < 0)
            goto done;
        xatlas::MeshDecl decl;
        decl.vertexCount = (uint32_t)vertex_count;
        decl.vertexPositionData = buffers[i].positions.buf;
        decl.vertexPositionStride = 3 * sizeof(float);
        decl.indexCount = (uint32_t)(3 * face_count);
        decl.indexData = buffers[i].indices.buf;
        decl.indexFormat = xatlas::IndexFormat::UInt32;
        // xatlas reads the buffers only here (it copies the mesh)
        const xatlas::AddMeshError error = xatlas::AddMesh(handle.atlas, decl);
        if (error != xatlas::AddMeshError::Success) {
            PyErr_Format(PyExc_ValueError, "Adding mesh failed: %s", xatlas::StringForEnum(error));
            goto done;
        }
    }
    {
        xatlas::ChartOptions chart_options;
        chart_options.maxChartArea = max_chart_area;
        xatlas::PackOptions pack_options;
        pack_options.padding = 0;
        pack_options.bilinear = false;
        pack_options.texelsPerUnit = texels_per_unit;
        pack_options.aobakeChartsOnly = charts_only != 0;
        Py_BEGIN_ALLOW_THREADS
        xatlas::Generate(handle.atlas, chart_options, pack_options);
        Py_END_ALLOW_THREADS
    }
    {
        const xatlas::Atlas *atlas = handle.atlas;
        PyObject *list = PyList_New((Py_ssize_t)atlas->meshCount);
        if (!list) goto done;
        for (uint32_t m = 0; m < atlas->meshCount; m++) {
            const xatlas::Mesh &mesh = atlas->meshes[m];
            PyObject *vmapping =
                PyBytes_FromStringAndSize(nullptr, 4 * (Py_ssize_t)mesh.vertexCount);
            PyObject *faces = PyBytes_FromStringAndSize(nullptr, 4 * (Py_ssize_t)mesh.indexCount);
            PyObject *uv = PyBytes_FromStringAndSize(nullptr, 8 * (Py_ssize_t)mesh.vertexCount);
            if (!vmapping || !faces || !uv) {
                Py_XDECREF(vmapping);
                Py_XDECREF(faces);
                Py_XDECREF(uv);
                Py_DECREF(list);
                goto done;
            }
            uint32_t *xref = (uint32_t *)PyBytes_AS_STRING(vmapping);
            float *st = (float *)PyBytes_AS_STRING(uv);
            for (uint32_t v = 0; v < mesh.vertexCount; v++) {
                const xatlas::Vertex &vertex = mesh.vertexArray[v];
                xref[v] = vertex.xref;
                if (charts_only) {  // in texels: there is no atlas to divide by
                    st[2 * v] = vertex.uv[0];
                    st[2 * v + 1] = vertex.uv[1];
                } else {  // as xatlas-python: float / uint32 -> float
                    st[2 * v] = vertex.uv[0] / atlas->width;
                    st[2 * v + 1] = vertex.uv[1] / atlas->height;
                }
            }
            std::memcpy(PyBytes_AS_STRING(faces), mesh.indexArray, 4 * (size_t)mesh.indexCount);
            PyObject *item = Py_BuildValue("(NNN)", vmapping, faces, uv);  // takes all three
            if (!item) {
                Py_DECREF(list);
                goto done;
            }
            PyList_SET_ITEM(list, m, item);
        }
        result = Py_BuildValue("(IIN)", charts_only ? 1u : atlas->width,
                               charts_only ? 1u : atlas->height, list);
    }
done:
    delete[] buffers;
    Py_DECREF(seq);
    return result;
}

PyMethodDef methods[] = {
    {"chart", chart, METH_VARARGS,
     "chart(meshes, max_chart_area, texels_per_unit, charts_only=False) -> (width, height, "
     "[(vmapping, indices, uv) bytes per mesh]): xatlas charts, packed without padding or "
     "only transformed as packing does (see aobake/_xatlas.cpp)"},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef module = {PyModuleDef_HEAD_INIT, "aobake._xatlas",
                      "xatlas's charting, built from third_party/xatlas", -1, methods};

}  // namespace

PyMODINIT_FUNC PyInit__xatlas(void) { return PyModule_Create(&module); }
