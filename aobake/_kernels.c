/* aobake._kernels: aobake's compiled kernels, one C file per stage, each the compiled twin
 * of a Python module whose numpy formulation stays the reference (and the fallback when
 * this extension was not built); tests check each pair agrees bit for bit:
 *
 *   _rays.c     fill_rays                     aobake.rays (samplers, warps): ray generation
 *   _counts.c   row_counts                    aobake.quantities.ao: escape counts
 *   _raster.c   raster_rows                   aobake.targets.texels.raster: the rasteriser
 *   _surface.c  surface_interp, _shading      aobake.targets.texels.surface: sample points
 *   _seams.c    seam_pattern, seam_values     aobake.targets.texels.seams: the normal matrix
 *   _sparse.c   seam_csr_cg                   aobake.sparse: conjugate gradients
 *   _post.c     dilate_rings                  aobake.post: gutter dilation
 *   _sort.c     radix_argsort                 aobake.rng.stable_argsort
 *   _pack.c     chart_marks, pack_charts      aobake.targets.texels.packing: the atlas packer
 *   _unionfind.c parity_union_find            aobake.repair: components and their 2-colouring
 *   _normals.c  triangle_normals, vertex_normal_sums  aobake.scene: face and vertex normals
 *   _pixels.c   pixel_rays, box_rays          aobake.targets.view_box: a box view's rays
 *   _obj.c      obj_floats, obj_corners       aobake.obj: the OBJ fast reader's blocks
 *   _orient.c   orient_terms, orient_volumes  aobake.repair.orient: its per-face terms
 *
 * This file holds the module's method table; _kernels.h what the files share (buffer
 * checks, the splitmix64 hash of aobake.rng, the functions' declarations).
 *
 * Exactness: every operation is a single IEEE-754 operation rounded in the same precision
 * as its numpy counterpart, in the same order; setup.py compiles with -ffp-contract=off so
 * no multiply-add is fused (numpy never fuses).
 */
#include "_kernels.h"

static PyMethodDef methods[] = {
    {"fill_rays", fill_rays, METH_VARARGS,
     "fill_rays(origins, normals, keys, table, sampler, weighting, nx, ny, k, R, m, js, mp, "
     "out_origins, out_directions): write point-major ray origins and directions."},
    {"pixel_rays", pixel_rays, METH_VARARGS,
     "pixel_rays(pixels, keys, net, R, q0, count, m, width, height, sx, sy, half_w, half_h, "
     "basis, out_where, out_directions, out_directions32): a box view's sobol positions and "
     "the camera rays through them."},
    {"box_rays", box_rays, METH_VARARGS,
     "box_rays(directions, t, prim, faces, eye, center, scale, up, height, ground_size, "
     "fraction, ulps, keys, slots, table, sampler, weighting, r, m, out_origins, "
     "out_directions): a box view's AO rays from its positions' primary hits."},
    {"obj_floats", obj_floats, METH_VARARGS,
     "obj_floats(block, count, key, least) -> (w, bytearray) | None: the values of count "
     "lines 'KEY x1 ... xw' (aobake.obj._floats)."},
    {"obj_corners", obj_corners, METH_VARARGS,
     "obj_corners(block, count) -> (per_face, vertex, texture, normal, has_texture, "
     "has_normal) | None: the corners of count f lines (aobake.obj._corners)."},
    {"orient_terms", orient_terms, METH_VARARGS,
     "orient_terms(vertices, corners, normals, out_area, out_mean, out_agree) -> bool: "
     "the winding check's per-face areas, mean corners and normal votes."},
    {"orient_volumes", orient_volumes, METH_VARARGS,
     "orient_volumes(vertices, corners, centre, comp, out_det) -> bool: the winding "
     "check's per-face volume terms about each component's centre."},
    {"raster_rows", raster_rows, METH_VARARGS,
     "raster_rows(ax, ay, dx, dy, owner, corner, vmax, verts, c0, c1, row_start, row_tris, width, "
     "n_sub, seed_key, q, g, row_lo, row_hi, write, rows, out_texel, out_face, out_bary, "
     "out_sample, out_fallback, coverage, shared): the rasteriser, rows in final order."},
    {"row_counts", row_counts, METH_VARARGS,
     "row_counts(flags, rows, m, out): nonzero flags per row of m."},
    {"radix_argsort", radix_argsort, METH_VARARGS,
     "radix_argsort(keys, bits, out_order, out_sorted): stable argsort of uint32 keys."},
    {"surface_interp", surface_interp, METH_VARARGS,
     "surface_interp(positions, normals, faces, face, bary, out_points, out_normals, out_length): "
     "lightmap sample points and unit shading normals."},
    {"surface_shading", surface_shading, METH_VARARGS,
     "surface_shading(face, unit, has_face, turned, normals, length, out) -> (fixed, turned): "
     "lightmap samples' shading normals (surface_points' rule)."},
    {"dilate_rings", dilate_rings, METH_VARARGS,
     "dilate_rings(out, filled, height, width, channels, padding) -> rings: "
     "aobake.post.dilate's rings in place"},
    {"seam_pattern", seam_pattern, METH_VARARGS,
     "seam_pattern(starts, slots, gutter, fill_to, fill_from[, threads]) -> (indptr, indices) "
     "bytes: the seam erasure's normal matrix's CSR pattern."},
    {"seam_values", seam_values, METH_VARARGS,
     "seam_values(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, indptr, "
     "indices[, threads]) -> data bytes: its values on that pattern."},
    {"seam_csr_cg", seam_csr_cg, METH_VARARGS,
     "seam_csr_cg(indptr, indices, data, diag, rhs, b, x, tolerance, max_iterations[, threads]) "
     "-> (iterations, max |r / diag|): the seam erasure's Jacobi-preconditioned CG."},
    {"chart_marks", chart_marks, METH_VARARGS,
     "chart_marks(xy, faces, face_chart, mask_offset, size, padding, out_covered, out_padded): "
     "the atlas packer's chart masks (packing._chart_masks)."},
    {"pack_charts", pack_charts, METH_VARARGS,
     "pack_charts(masks, offsets, shapes, order, width, height, upright, hole_cap, hole_run, "
     "hole_rows, max_searches, out_place[, state]) -> (fits, placed, used): "
     "packing._pack_in_order."},
    {"parity_union_find", parity_union_find, METH_VARARGS,
     "parity_union_find(a, b, odd, out_root, out_parity): repair._parity_union_find's "
     "(root, parity), written."},
    {"triangle_normals", triangle_normals, METH_VARARGS,
     "triangle_normals(vertices, faces, out_unit, out_length, out_cross, out_cos) -> bool: "
     "unit face normals, their cross products' lengths, and (where not empty) the cross "
     "products and each corner's clipped cosine (aobake.scene)."},
    {"vertex_normal_sums", vertex_normal_sums, METH_VARARGS,
     "vertex_normal_sums(faces, rows, angles, out) -> bool: vertex_normals's weighted sums "
     "in bincount's order, normalised."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "aobake._kernels",
    "Compiled per-ray kernels of aobake (see aobake.rays).", -1, methods,
};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
