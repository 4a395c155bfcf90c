/* aobake._embree: Embree 4 queries straight from C, on the library embreex ships.
 *
 * Why it exists (benchmarks/bench_backend.py, docs/performance.md): embreex's run() traces
 * one ray at a time (rtcOccluded1), no faster than a bare C loop of it.  An AO point's rays
 * leave one origin, so consecutive ones make coherent packets, with the same hits.  Which
 * width is fastest depends on the CPU (docs/performance.md, benchmarks/bench_packet_width.py):
 * on an AVX-512 machine rtcOccluded16 answered the bunny's rays 1.6x faster than embreex
 * and the ogre's 1.2x (8 lanes: 1.4x, 1.1x); on an AVX2 AMD EPYC, where Embree traces 8
 * lanes natively and splits a packet of 16 into two, 8 lanes were the fastest (bunny 1.19x
 * one ray at a time, 1.39x 16 lanes; the ogre within a few percent at every width).  So the
 * queries use the width Embree reports as native (aobake/backends/native.py chooses).
 * Occlusion is a per-ray boolean (does any triangle cross the segment?), so a packet's
 * answer for a ray does not depend on the rays beside it: the packing cannot make results
 * depend on chunking or width.  Closest-hit queries stay one ray at a
 * time (rtcIntersect1, as embreex), so their tie-breaking never depends on packet mates.
 *
 * Instances (aobake/instances.py, backends/instanced.py): one committed child scene per
 * unique mesh and a top-level scene of RTC_GEOMETRY_TYPE_INSTANCE geometries, one per
 * placement (rtcSetGeometryInstancedScene, rtcSetGeometryTransform), so the acceleration
 * structures grow with the unique triangles and the placements, not with their product.
 * The same occlusion packets answer on the top-level scene; intersect_instanced also says
 * which instance a hit is in.
 *
 * No link-time dependency: the headers are Embree's own (third_party/embree4, Apache-2.0,
 * for the types and constants), and open() takes the path of the libembree4 that embreex
 * loaded and finds each function with dlsym.  Arrays arrive through the buffer protocol.
 * Every query releases the GIL (the tracer's threads run them side by side).
 */
#include <dlfcn.h>
#include <math.h>
#include <string.h>

#include "_kernels.h" /* Python.h, check() */

#include "embree4/rtcore.h"

/* The functions used, as pointers found in the loaded library. */
#define EMBREE_FUNCTIONS(X)                                                              \
    X(rtcNewDevice) X(rtcReleaseDevice) X(rtcGetDeviceError) X(rtcGetDeviceProperty)      \
    X(rtcNewScene) X(rtcSetSceneFlags) X(rtcNewGeometry) X(rtcSetNewGeometryBuffer)       \
    X(rtcSetSharedGeometryBuffer)                                                          \
    X(rtcCommitGeometry) X(rtcAttachGeometry) X(rtcReleaseGeometry) X(rtcCommitScene)     \
    X(rtcReleaseScene) X(rtcOccluded1) X(rtcOccluded4) X(rtcOccluded8) X(rtcOccluded16)   \
    X(rtcIntersect1) X(rtcSetGeometryInstancedScene) X(rtcSetGeometryTransform)          \
    X(rtcAttachGeometryByID)

#define DECLARE(name) static __typeof__(&name) p_##name;
EMBREE_FUNCTIONS(DECLARE)
#undef DECLARE

static void *library;
static RTCDevice device;
static int packet_width; /* 16, 8, 4 or 1: the widest packet this CPU's Embree answers */
/* 16, 8, 4 or 1: the widest packet Embree traces natively here (its device properties); a
 * wider one works but is split into native ones inside Embree (16 on AVX2: two of 8). */
static int native_width;

#define SCENE_CAPSULE "aobake._embree.scene"

static int device_error(const char *what)
{
    enum RTCError code = p_rtcGetDeviceError(device);
    if (code == RTC_ERROR_NONE)
        return 0;
    PyErr_Format(PyExc_RuntimeError, "Embree: %s failed (error %d)", what, (int)code);
    return -1;
}

/* A committed scene of one triangle mesh; vertices (nv, 3) float32, faces (nf, 3) uint32.
 * shared 0: Embree owns copies of both (its own buffers carry the padding its SIMD loads
 * need); shared 1: Embree reads the caller's arrays in place (the vertices padded by the
 * caller, one float beyond the last vertex, and both kept alive and unchanged while the
 * scene lives: new_scene holds them in the scene's capsule), so the mesh is not held twice
 * while the BVH is built, nor after. */
static RTCScene build(const float *vertices, Py_ssize_t nv, const uint32_t *faces,
                      Py_ssize_t nf, int robust, int shared)
{
    RTCScene scene = p_rtcNewScene(device);
    if (robust)
        p_rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
    RTCGeometry geometry = p_rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    if (shared) {
        p_rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                     vertices, 0, 3 * sizeof(float), (size_t)nv);
        p_rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                     faces, 0, 3 * sizeof(uint32_t), (size_t)nf);
    } else {
        float *v = p_rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0,
                                             RTC_FORMAT_FLOAT3, 3 * sizeof(float), (size_t)nv);
        uint32_t *f = p_rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0,
                                                RTC_FORMAT_UINT3, 3 * sizeof(uint32_t),
                                                (size_t)nf);
        if (v && f) {
            memcpy(v, vertices, (size_t)nv * 3 * sizeof(float));
            memcpy(f, faces, (size_t)nf * 3 * sizeof(uint32_t));
        }
    }
    p_rtcCommitGeometry(geometry);
    p_rtcAttachGeometry(scene, geometry);
    p_rtcReleaseGeometry(geometry);
    p_rtcCommitScene(scene);
    return scene;
}

/* The arrays a scene built on shared buffers reads (its capsule's context). */
typedef struct {
    Py_buffer vertices, faces;
} SharedArrays;

static void release_scene(PyObject *capsule)
{
    RTCScene scene = PyCapsule_GetPointer(capsule, SCENE_CAPSULE);
    if (scene)
        p_rtcReleaseScene(scene);
    SharedArrays *arrays = PyCapsule_GetContext(capsule);
    if (arrays) { /* after the scene: Embree no longer reads them */
        PyBuffer_Release(&arrays->vertices);
        PyBuffer_Release(&arrays->faces);
        PyMem_Free(arrays);
    }
}

/* Does a packet of W rays work here?  (An ISA this CPU or this Embree build lacks sets an
 * error, or answers nothing.)  The probe scene's triangle is hit at t = 1 by rays up z. */
#define PROBE(W, ALIGN)                                                             \
    do {                                                                            \
        RTC_ALIGN(ALIGN) struct RTCRay##W r;                                        \
        RTC_ALIGN(ALIGN) int valid[W];                                              \
        memset(&r, 0, sizeof r);                                                    \
        for (int k = 0; k < W; k++) {                                               \
            valid[k] = -1;                                                          \
            r.dir_z[k] = 1.0f;                                                      \
            r.tfar[k] = 2.0f;                                                       \
            r.mask[k] = 0xFFFFFFFFu;                                                \
        }                                                                           \
        p_rtcGetDeviceError(device); /* clear */                                    \
        p_rtcOccluded##W(valid, probe, &r, NULL);                                   \
        return p_rtcGetDeviceError(device) == RTC_ERROR_NONE && r.tfar[0] < 0;      \
    } while (0)

static int probe_width(RTCScene probe, int width)
{
    if (width == 16)
        PROBE(16, 64);
    if (width == 8)
        PROBE(8, 32);
    PROBE(4, 16);
}

/* open(path) -> (version, widest packet, native packet): load libembree4 (the file embreex
 * loaded), make the device, find the widest occlusion packet that works here and the widest
 * Embree traces natively on this CPU. */
static PyObject *open_library(PyObject *self, PyObject *args)
{
    const char *path;
    if (!PyArg_ParseTuple(args, "s", &path))
        return NULL;
    if (library == NULL) {
        void *handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
        if (handle == NULL) {
            PyErr_Format(PyExc_OSError, "cannot load %s: %s", path, dlerror());
            return NULL;
        }
#define FIND(name)                                                                  \
        p_##name = (__typeof__(&name))dlsym(handle, #name);                         \
        if (p_##name == NULL) {                                                     \
            PyErr_Format(PyExc_OSError, "%s has no %s", path, #name);               \
            dlclose(handle);                                                        \
            return NULL;                                                            \
        }
        EMBREE_FUNCTIONS(FIND)
#undef FIND
        device = p_rtcNewDevice(NULL);
        if (device == NULL) {
            PyErr_SetString(PyExc_RuntimeError, "Embree: rtcNewDevice failed");
            dlclose(handle);
            return NULL;
        }
        long version = (long)p_rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_VERSION);
        if (version / 10000 != RTC_VERSION_MAJOR) {
            PyErr_Format(PyExc_OSError, "%s is Embree %ld, not %d.x", path, version,
                         RTC_VERSION_MAJOR);
            p_rtcReleaseDevice(device);
            device = NULL;
            dlclose(handle);
            return NULL;
        }
        /* Probe the packet widths on one triangle: an unsupported width sets an error. */
        const float tri[9] = {-1, -1, 1, 1, -1, 1, 0, 1, 1};
        const uint32_t idx[3] = {0, 1, 2};
        RTCScene probe = build(tri, 3, idx, 1, 1, 0);
        if (device_error("building a probe scene")) {
            p_rtcReleaseScene(probe);
            p_rtcReleaseDevice(device);
            device = NULL;
            dlclose(handle);
            return NULL;
        }
        packet_width = 1;
        if (probe_width(probe, 16))
            packet_width = 16;
        else if (probe_width(probe, 8))
            packet_width = 8;
        else if (probe_width(probe, 4))
            packet_width = 4;
        p_rtcReleaseScene(probe);
        native_width = 1;
        if (p_rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED))
            native_width = 16;
        else if (p_rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED))
            native_width = 8;
        else if (p_rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED))
            native_width = 4;
        if (native_width > packet_width)
            native_width = packet_width;
        library = handle;
    }
    return Py_BuildValue("(lii)", (long)p_rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_VERSION),
                         packet_width, native_width);
}

/* scene(vertices float32 (nv*3), faces uint32 (nf*3), robust) -> capsule.  Vertices of at
 * least nv*3 + 1 floats (padded for Embree's 16-byte loads) are read in place, with the
 * faces: the capsule keeps both buffers (their exporters cannot resize them meanwhile). */
static PyObject *new_scene(PyObject *self, PyObject *args)
{
    Py_buffer vb = {0}, fb = {0};
    Py_ssize_t nv, nf;
    int robust;
    if (library == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "aobake._embree.open() was not called");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "y*ny*np", &vb, &nv, &fb, &nf, &robust))
        return NULL;
    PyObject *result = NULL;
    int padded = vb.len == (3 * nv + 1) * (Py_ssize_t)sizeof(float);
    if (check(&vb, "vertices", sizeof(float), 3 * nv + padded) || check(&fb, "faces", 4, 3 * nf))
        goto done;
    for (Py_ssize_t i = 0; i < 3 * nf; i++) { /* Embree would read past the vertices */
        uint32_t corner = ((const uint32_t *)fb.buf)[i];
        if ((Py_ssize_t)corner >= nv) {
            PyErr_Format(PyExc_ValueError, "faces: index %u of %zd vertices", corner, nv);
            goto done;
        }
    }
    int shared = padded && ((uintptr_t)vb.buf % sizeof(float)) == 0 &&
                 ((uintptr_t)fb.buf % 4) == 0;
    SharedArrays *arrays = NULL;
    if (shared) {
        arrays = PyMem_Malloc(sizeof(SharedArrays));
        if (arrays == NULL) {
            PyErr_NoMemory();
            goto done;
        }
    }
    RTCScene scene;
    Py_BEGIN_ALLOW_THREADS
    scene = build(vb.buf, nv, fb.buf, nf, robust, shared);
    Py_END_ALLOW_THREADS
    if (device_error("building the scene")) {
        p_rtcReleaseScene(scene);
        PyMem_Free(arrays);
        goto done;
    }
    result = PyCapsule_New(scene, SCENE_CAPSULE, release_scene);
    if (result == NULL) {
        p_rtcReleaseScene(scene);
        PyMem_Free(arrays);
        goto done;
    }
    if (arrays) { /* the capsule owns the two buffer views now */
        arrays->vertices = vb;
        arrays->faces = fb;
        PyCapsule_SetContext(result, arrays);
        return result;
    }
done:
    PyBuffer_Release(&vb);
    PyBuffer_Release(&fb);
    return result;
}

/* instances(meshes, mesh_of i32 (n), transforms f32 (n*12), robust) -> capsule: a
 * committed top-level scene of n instances; meshes is a sequence of (vertices f32 (nv*3),
 * nv, faces u32 (nf*3), nf), each committed once as a child scene; instance i (geometry id
 * i) places mesh mesh_of[i] by the 3x4 row-major matrix transforms[12 i ..] (object ->
 * the tracer's local frame).  A negative mesh_of leaves id i empty (a degenerate
 * placement: it would occlude nothing). */
static PyObject *new_instances(PyObject *self, PyObject *args)
{
    PyObject *meshes;
    Py_buffer mb = {0}, xb = {0};
    int robust;
    if (library == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "aobake._embree.open() was not called");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "Oy*y*p", &meshes, &mb, &xb, &robust))
        return NULL;
    PyObject *result = NULL, *sequence = NULL;
    RTCScene *children = NULL, top = NULL;
    Py_ssize_t k = 0, n = mb.len / 4;
    if (check(&mb, "mesh_of", 4, n) || check(&xb, "transforms", 4, 12 * n))
        goto done;
    sequence = PySequence_Fast(meshes, "meshes must be a sequence");
    if (sequence == NULL)
        goto done;
    k = PySequence_Fast_GET_SIZE(sequence);
    const int32_t *mesh_of = mb.buf;
    for (Py_ssize_t i = 0; i < n; i++)
        if (mesh_of[i] >= k) {
            PyErr_Format(PyExc_ValueError, "mesh_of: %d of %zd meshes", mesh_of[i], k);
            goto done;
        }
    children = PyMem_Calloc(k ? (size_t)k : 1, sizeof(RTCScene));
    if (children == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t j = 0; j < k; j++) {
        Py_buffer vb = {0}, fb = {0};
        Py_ssize_t nv, nf;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(sequence, j), "y*ny*n", &vb, &nv, &fb,
                              &nf))
            goto done;
        int bad = check(&vb, "vertices", sizeof(float), 3 * nv) || check(&fb, "faces", 4, 3 * nf);
        for (Py_ssize_t i = 0; !bad && i < 3 * nf; i++) {
            uint32_t corner = ((const uint32_t *)fb.buf)[i];
            if ((Py_ssize_t)corner >= nv) {
                PyErr_Format(PyExc_ValueError, "mesh %zd faces: index %u of %zd vertices", j,
                             corner, nv);
                bad = 1;
            }
        }
        if (!bad) {
            Py_BEGIN_ALLOW_THREADS
            children[j] = build(vb.buf, nv, fb.buf, nf, robust, 0);
            Py_END_ALLOW_THREADS
        }
        PyBuffer_Release(&vb);
        PyBuffer_Release(&fb);
        if (bad || device_error("building an instanced mesh"))
            goto done;
    }
    const float *xf = xb.buf;
    Py_BEGIN_ALLOW_THREADS
    top = p_rtcNewScene(device);
    if (robust)
        p_rtcSetSceneFlags(top, RTC_SCENE_FLAG_ROBUST);
    for (Py_ssize_t i = 0; i < n; i++) {
        if (mesh_of[i] < 0)
            continue;
        RTCGeometry instance = p_rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
        p_rtcSetGeometryInstancedScene(instance, children[mesh_of[i]]);
        p_rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, xf + 12 * i);
        p_rtcCommitGeometry(instance);
        p_rtcAttachGeometryByID(top, instance, (unsigned int)i);
        p_rtcReleaseGeometry(instance);
    }
    p_rtcCommitScene(top);
    Py_END_ALLOW_THREADS
    if (device_error("building the instances")) {
        p_rtcReleaseScene(top);
        goto done;
    }
    result = PyCapsule_New(top, SCENE_CAPSULE, release_scene);
    if (result == NULL)
        p_rtcReleaseScene(top);
done:
    /* the instances hold their child scenes (Embree counts references): ours go */
    for (Py_ssize_t j = 0; children != NULL && j < k; j++)
        if (children[j])
            p_rtcReleaseScene(children[j]);
    PyMem_Free(children);
    Py_XDECREF(sequence);
    PyBuffer_Release(&mb);
    PyBuffer_Release(&xb);
    return result;
}

/* Lane k of a packet from ray i: origin, direction, segment (0, tfar]. */
#define FILL_LANE(r, k, i)                                          \
    do {                                                            \
        (r).org_x[k] = org[3 * (i)];                                \
        (r).org_y[k] = org[3 * (i) + 1];                            \
        (r).org_z[k] = org[3 * (i) + 2];                            \
        (r).dir_x[k] = dir[3 * (i)];                                \
        (r).dir_y[k] = dir[3 * (i) + 1];                            \
        (r).dir_z[k] = dir[3 * (i) + 2];                            \
        (r).tnear[k] = 0.0f;                                        \
        (r).tfar[k] = tfar[i];                                      \
        (r).time[k] = 0.0f;                                         \
        (r).mask[k] = 0xFFFFFFFFu;                                  \
        (r).id[k] = 0;                                              \
        (r).flags[k] = 0;                                           \
    } while (0)

/* Packets of W rays (W = 16, 8 or 4): the last packet's idle lanes repeat its last ray. */
#define OCCLUDE_PACKETS(W, ALIGN)                                                   \
    do {                                                                            \
        RTC_ALIGN(ALIGN) struct RTCRay##W r;                                        \
        RTC_ALIGN(ALIGN) int valid[W];                                              \
        for (Py_ssize_t i = 0; i < n; i += W) {                                     \
            int lanes = n - i < W ? (int)(n - i) : W;                               \
            for (int k = 0; k < W; k++) {                                           \
                Py_ssize_t j = i + (k < lanes ? k : lanes - 1);                     \
                valid[k] = k < lanes ? -1 : 0;                                      \
                FILL_LANE(r, k, j);                                                 \
            }                                                                       \
            p_rtcOccluded##W(valid, scene, &r, NULL);                               \
            for (int k = 0; k < lanes; k++)                                         \
                out[i + k] = r.tfar[k] < 0.0f; /* a hit sets tfar to -inf */        \
        }                                                                           \
    } while (0)

static void occlude(RTCScene scene, const float *org, const float *dir, const float *tfar,
                    uint8_t *out, Py_ssize_t n, int width)
{
    if (width == 16) {
        OCCLUDE_PACKETS(16, 64);
    } else if (width == 8) {
        OCCLUDE_PACKETS(8, 32);
    } else if (width == 4) {
        OCCLUDE_PACKETS(4, 16);
    } else {
        for (Py_ssize_t i = 0; i < n; i++) {
            struct RTCRay r = {org[3 * i], org[3 * i + 1], org[3 * i + 2], 0.0f,
                               dir[3 * i], dir[3 * i + 1], dir[3 * i + 2], 0.0f,
                               tfar[i], 0xFFFFFFFFu, 0, 0};
            p_rtcOccluded1(scene, &r, NULL);
            out[i] = r.tfar < 0.0f;
        }
    }
}

static RTCScene scene_of(PyObject *capsule)
{
    return PyCapsule_GetPointer(capsule, SCENE_CAPSULE);
}

/* occluded(scene, origins f32 (n*3), directions f32 (n*3), tfar f32 (n), out u8 (n), width):
 * width 16, 8, 4 (packets, at most open()'s) or 1 (one ray at a time). */
static PyObject *occluded(PyObject *self, PyObject *args)
{
    PyObject *capsule;
    Py_buffer ob = {0}, db = {0}, tb = {0}, hb = {0};
    int width;
    if (!PyArg_ParseTuple(args, "Oy*y*y*w*i", &capsule, &ob, &db, &tb, &hb, &width))
        return NULL;
    PyObject *result = NULL;
    RTCScene scene = scene_of(capsule);
    Py_ssize_t n = hb.len;
    if (scene == NULL || check(&ob, "origins", 4, 3 * n) || check(&db, "directions", 4, 3 * n)
        || check(&tb, "tfar", 4, n) || check(&hb, "out", 1, n))
        goto done;
    if (!(width == 1 || width == 4 || width == 8 || width == 16) || width > packet_width) {
        PyErr_Format(PyExc_ValueError, "width %d: 1, 4, 8 or 16, at most %d here", width,
                     packet_width);
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    occlude(scene, ob.buf, db.buf, tb.buf, hb.buf, n, width);
    Py_END_ALLOW_THREADS
    if (device_error("rtcOccluded"))
        goto done;
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&ob);
    PyBuffer_Release(&db);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&hb);
    return result;
}

/* One ray's nearest hit within (0, tfar] (rtcIntersect1): its face, -1 on a miss; *t is
 * Embree's tfar after the query (the hit's distance, or tfar unchanged on a miss). */
static int64_t nearest1(RTCScene scene, const float *org, const float *dir, float tfar,
                        float *t)
{
    struct RTCRayHit rh;
    rh.ray = (struct RTCRay){org[0], org[1], org[2], 0.0f, dir[0], dir[1], dir[2], 0.0f,
                             tfar, 0xFFFFFFFFu, 0, 0};
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    p_rtcIntersect1(scene, &rh, NULL);
    *t = rh.ray.tfar;
    return rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? -1 : (int64_t)rh.hit.primID;
}

/* intersect(scene, origins, directions, tfar, t out f32 (n), prim out i32 (n)): the nearest
 * hit within (0, tfar]; t = tfar unchanged and prim = -1 on a miss. */
static PyObject *intersect(PyObject *self, PyObject *args)
{
    PyObject *capsule;
    Py_buffer ob = {0}, db = {0}, tb = {0}, rt = {0}, rp = {0};
    if (!PyArg_ParseTuple(args, "Oy*y*y*w*w*", &capsule, &ob, &db, &tb, &rt, &rp))
        return NULL;
    PyObject *result = NULL;
    RTCScene scene = scene_of(capsule);
    Py_ssize_t n = tb.len / 4;
    if (scene == NULL || check(&ob, "origins", 4, 3 * n) || check(&db, "directions", 4, 3 * n)
        || check(&tb, "tfar", 4, n) || check(&rt, "t", 4, n) || check(&rp, "prim", 4, n))
        goto done;
    const float *org = ob.buf, *dir = db.buf, *tfar = tb.buf;
    float *t = rt.buf;
    int32_t *prim = rp.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++)
        prim[i] = (int32_t)nearest1(scene, org + 3 * i, dir + 3 * i, tfar[i], t + i);
    Py_END_ALLOW_THREADS
    if (device_error("rtcIntersect1"))
        goto done;
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&ob);
    PyBuffer_Release(&db);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&rt);
    PyBuffer_Release(&rp);
    return result;
}

/* intersect_instanced(scene, origins, directions, tfar, t out f32 (n), prim out i32 (n),
 * instance out i32 (n)): the nearest hit within (0, tfar] of an instances() scene, as
 * intersect() (one ray at a time), with the instance it is in (-1 on a miss). */
static PyObject *intersect_instanced(PyObject *self, PyObject *args)
{
    PyObject *capsule;
    Py_buffer ob = {0}, db = {0}, tb = {0}, rt = {0}, rp = {0}, ri = {0};
    if (!PyArg_ParseTuple(args, "Oy*y*y*w*w*w*", &capsule, &ob, &db, &tb, &rt, &rp, &ri))
        return NULL;
    PyObject *result = NULL;
    RTCScene scene = scene_of(capsule);
    Py_ssize_t n = tb.len / 4;
    if (scene == NULL || check(&ob, "origins", 4, 3 * n) || check(&db, "directions", 4, 3 * n)
        || check(&tb, "tfar", 4, n) || check(&rt, "t", 4, n) || check(&rp, "prim", 4, n)
        || check(&ri, "instance", 4, n))
        goto done;
    const float *org = ob.buf, *dir = db.buf, *tfar = tb.buf;
    float *t = rt.buf;
    int32_t *prim = rp.buf, *inst = ri.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        const float *o = org + 3 * i, *d = dir + 3 * i;
        struct RTCRayHit rh;
        rh.ray = (struct RTCRay){o[0], o[1], o[2], 0.0f, d[0], d[1], d[2], 0.0f, tfar[i],
                                 0xFFFFFFFFu, 0, 0};
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        p_rtcIntersect1(scene, &rh, NULL);
        t[i] = rh.ray.tfar;
        int hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        prim[i] = hit ? (int32_t)rh.hit.primID : -1;
        inst[i] = hit ? (int32_t)rh.hit.instID[0] : -1;
    }
    Py_END_ALLOW_THREADS
    if (device_error("rtcIntersect1"))
        goto done;
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&ob);
    PyBuffer_Release(&db);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&rt);
    PyBuffer_Release(&rp);
    PyBuffer_Release(&ri);
    return result;
}

/* One alpha-tested face's alpha at a point (as aobake.backends.cutout.alpha_at, the same
 * float64 operations in the same order): barycentrics from the corners, the UV, the
 * material's factor times its image bilinearly (repeat wrapping, texel centres at
 * (i + 0.5) / W, v = 0 at the image's bottom). */
typedef struct {
    const double *corners, *uv, *normals, *factor, *cutoff;
    const int64_t *material, *offset, *width, *height;
    const float *pixels;
} Cutout;

static double cutout_alpha(const Cutout *c, Py_ssize_t f, const double p[3])
{
    const double *v = c->corners + 9 * f;
    double e1[3], e2[3], q[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = v[3 + k] - v[k];
        e2[k] = v[6 + k] - v[k];
        q[k] = p[k] - v[k];
    }
    double d11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
    double d12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2];
    double d22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2];
    double q1 = q[0] * e1[0] + q[1] * e1[1] + q[2] * e1[2];
    double q2 = q[0] * e2[0] + q[1] * e2[1] + q[2] * e2[2];
    double det = d11 * d22 - d12 * d12;
    double safe = det > 0 ? det : 1.0;
    double b1 = (d22 * q1 - d12 * q2) / safe;
    double b2 = (d11 * q2 - d12 * q1) / safe;
    double b0 = 1.0 - b1 - b2;
    const double *t = c->uv + 6 * f;
    double u = b0 * t[0] + b1 * t[2] + b2 * t[4];
    double w = b0 * t[1] + b1 * t[3] + b2 * t[5];
    int64_t m = c->material[f];
    double alpha = c->factor[m];
    if (c->offset[m] < 0)
        return alpha;
    int64_t width = c->width[m], height = c->height[m];
    const float *image = c->pixels + c->offset[m];
    double x = u * (double)width - 0.5, y = (1.0 - w) * (double)height - 0.5;
    double x0 = floor(x), y0 = floor(y);
    double fx = x - x0, fy = y - y0;
    int64_t i0 = ((int64_t)x0 % width + width) % width;
    int64_t j0 = ((int64_t)y0 % height + height) % height;
    int64_t i1 = (i0 + 1) % width, j1 = (j0 + 1) % height;
    double a00 = image[j0 * width + i0], a01 = image[j0 * width + i1];
    double a10 = image[j1 * width + i0], a11 = image[j1 * width + i1];
    return alpha * ((1 - fx) * (1 - fy) * a00 + fx * (1 - fy) * a01 + (1 - fx) * fy * a10
                    + fx * fy * a11);
}

/* One ray through the alpha-tested faces (as aobake.backends.cutout.march, per ray): the
 * nearest hit; an opaque texel ends it (t = the distance travelled, prim its face), a
 * cut-out one is stepped past by `step` and the ray cast again, up to `layers` times
 * (then it is blocked where it is: t travelled, prim -1); a miss gives inf and -1. */
static int cutout_march(RTCScene scene, const Cutout *c, const float *org0, const float *dir,
                        float limit, float step, int layers, int front, float *t_out,
                        int64_t *prim_out)
{
    float org[3] = {org0[0], org0[1], org0[2]};
    float travelled = 0.0f;
    for (int layer = 0; layer < layers; layer++) {
        float remaining = limit - travelled;
        if (!(remaining > 0.0f)) /* np.maximum(x, 0): a zero limit once at the end */
            remaining = 0.0f;
        float t;
        int64_t hit = nearest1(scene, org, dir, remaining, &t);
        if (hit < 0) {
            *t_out = INFINITY;
            *prim_out = -1;
            return layer + 1;
        }
        Py_ssize_t f = (Py_ssize_t)hit;
        double d[3] = {dir[0], dir[1], dir[2]};
        double p[3];
        for (int k = 0; k < 3; k++)
            p[k] = (double)org[k] + (double)t * d[k];
        int solid = cutout_alpha(c, f, p) >= c->cutoff[c->material[f]];
        if (front) {
            const double *n = c->normals + 3 * f;
            solid = solid && (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) <= 0;
        }
        if (solid) {
            *t_out = travelled + t;
            *prim_out = (int64_t)f;
            return layer + 1;
        }
        float advance = t + step;
        travelled += advance;
        for (int k = 0; k < 3; k++)
            org[k] += advance * dir[k];
    }
    *t_out = travelled;
    *prim_out = -1;
    return layers;
}

/* march(scene, origins f32 (n*3), directions f32 (n*3), tmax f32 (n), corners f64 (k*9),
 * uv f64 (k*6), material i64 (k), normals f64 (k*3), factor f64 (m), cutoff f64 (m),
 * offset i64 (m) (-1: no image), width i64 (m), height i64 (m), pixels f32, step, layers,
 * front, t out f32 (n), prim out i64 (n)) -> the rays cast (recasts included): the cut-out
 * faces' first opaque hits. */
static PyObject *march(PyObject *self, PyObject *args)
{
    PyObject *capsule;
    Py_buffer b[15] = {{0}};
    float step;
    int layers, front;
    if (!PyArg_ParseTuple(args, "Oy*y*y*y*y*y*y*y*y*y*y*y*y*fipw*w*", &capsule, &b[0], &b[1],
                          &b[2], &b[3], &b[4], &b[5], &b[6], &b[7], &b[8], &b[9], &b[10],
                          &b[11], &b[12], &step, &layers, &front, &b[13], &b[14]))
        return NULL;
    PyObject *result = NULL;
    RTCScene scene = scene_of(capsule);
    Py_ssize_t n = b[2].len / 4, k = b[5].len / 8, m = b[7].len / 8, np_ = b[12].len / 4;
    if (scene == NULL || check(&b[0], "origins", 4, 3 * n) || check(&b[1], "directions", 4, 3 * n)
        || check(&b[2], "tmax", 4, n) || check(&b[3], "corners", 8, 9 * k)
        || check(&b[4], "uv", 8, 6 * k) || check(&b[5], "material", 8, k)
        || check(&b[6], "normals", 8, 3 * k) || check(&b[7], "factor", 8, m)
        || check(&b[8], "cutoff", 8, m) || check(&b[9], "offset", 8, m)
        || check(&b[10], "width", 8, m) || check(&b[11], "height", 8, m)
        || check(&b[12], "pixels", 4, np_) || check(&b[13], "t", 4, n)
        || check(&b[14], "prim", 8, n))
        goto done;
    Cutout c = {b[3].buf, b[4].buf, b[6].buf, b[7].buf, b[8].buf, b[5].buf, b[9].buf,
                b[10].buf, b[11].buf, b[12].buf};
    for (Py_ssize_t f = 0; f < k; f++) /* every face's material and image in range */
        if (c.material[f] < 0 || c.material[f] >= m) {
            PyErr_Format(PyExc_ValueError, "material: %lld of %zd", (long long)c.material[f], m);
            goto done;
        }
    for (Py_ssize_t i = 0; i < m; i++)
        if (c.offset[i] >= 0 && (c.width[i] < 1 || c.height[i] < 1 ||
                                 c.offset[i] + c.width[i] * c.height[i] > np_)) {
            PyErr_Format(PyExc_ValueError, "image %zd: outside the pixels", i);
            goto done;
        }
    const float *org = b[0].buf, *dir = b[1].buf, *tmax = b[2].buf;
    float *t = b[13].buf;
    int64_t *prim = b[14].buf;
    long long cast = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++)
        cast += cutout_march(scene, &c, org + 3 * i, dir + 3 * i, tmax[i], step, layers, front,
                             t + i, prim + i);
    Py_END_ALLOW_THREADS
    if (device_error("rtcIntersect1"))
        goto done;
    result = PyLong_FromLongLong(cast);
done:
    for (int i = 0; i < 15; i++)
        PyBuffer_Release(&b[i]);
    return result;
}

static PyMethodDef methods[] = {
    {"open", open_library, METH_VARARGS,
     "open(path) -> (version, widest packet, native packet): load libembree4 from path (once)."},
    {"scene", new_scene, METH_VARARGS,
     "scene(vertices f32, nv, faces u32, nf, robust) -> a committed triangle scene (vertices "
     "of nv*3 + 1 floats or more: both arrays read in place, kept by the scene)."},
    {"instances", new_instances, METH_VARARGS,
     "instances(meshes [(vertices f32, nv, faces u32, nf)], mesh_of i32, transforms f32 (n*12 "
     "row-major 3x4), robust) -> a committed scene of instances of committed child scenes."},
    {"intersect_instanced", intersect_instanced, METH_VARARGS,
     "intersect_instanced(scene, origins, directions, tfar, t, prim, instance): the nearest "
     "hit and its instance (-1: none)."},
    {"occluded", occluded, METH_VARARGS,
     "occluded(scene, origins, directions, tfar, out, width): out[i] = any hit in (0, tfar[i]]."},
    {"intersect", intersect, METH_VARARGS,
     "intersect(scene, origins, directions, tfar, t, prim): the nearest hit (prim -1: none)."},
    {"march", march, METH_VARARGS,
     "march(scene, origins, directions, tmax, corners, uv, material, normals, factor, cutoff, "
     "offset, width, height, pixels, step, layers, front, t, prim): alpha-tested first hits."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "aobake._embree",
                                    "Embree 4 occlusion packets (see aobake/_embree.c).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__embree(void)
{
    return PyModule_Create(&module);
}
