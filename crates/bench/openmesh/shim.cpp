// A C interface to OpenMesh (Debian's libopenmesh-dev, OpenMesh 9) for
// raymesh-mesh-peers: a triangle mesh built from indexed triangles, and
// the operations raymesh's half-edge mesh is compared on. Built only with
// the benchmark crate's `openmesh` feature; never part of the library.
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Tools/Subdivider/Uniform/LoopT.hh>

#include <chrono>
#include <cstdint>
#include <cstddef>
#include <new>
#include <vector>

typedef OpenMesh::TriMesh_ArrayKernelT<> Mesh;

extern "C" {

// Builds a mesh from `nv` points (xyz floats) and `nt` triangles (vertex
// indices); `*failed` counts the faces OpenMesh refused (non-manifold).
// Returns null on allocation failure.
void* raymesh_om_build(const float* pos, size_t nv, const uint32_t* tri, size_t nt, size_t* failed) {
    Mesh* m = new (std::nothrow) Mesh;
    if (!m) return nullptr;
    m->reserve(nv, 3 * nt / 2 + 3, nt);
    std::vector<Mesh::VertexHandle> vh(nv);
    for (size_t i = 0; i < nv; ++i) {
        vh[i] = m->add_vertex(Mesh::Point(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]));
    }
    size_t bad = 0;
    for (size_t t = 0; t < nt; ++t) {
        Mesh::FaceHandle f = m->add_face(vh[tri[3 * t]], vh[tri[3 * t + 1]], vh[tri[3 * t + 2]]);
        if (!f.is_valid()) ++bad;
    }
    *failed = bad;
    return m;
}

void raymesh_om_free(void* m) { delete static_cast<Mesh*>(m); }

size_t raymesh_om_vertices(const void* m) { return static_cast<const Mesh*>(m)->n_vertices(); }
size_t raymesh_om_edges(const void* m) { return static_cast<const Mesh*>(m)->n_edges(); }
size_t raymesh_om_faces(const void* m) { return static_cast<const Mesh*>(m)->n_faces(); }

// Every vertex's one-ring, clockwise (`vv_range`): the sum of the
// neighbours' indices, and their number in `*count`.
uint64_t raymesh_om_one_ring(const void* mp, uint64_t* count) {
    const Mesh& m = *static_cast<const Mesh*>(mp);
    uint64_t sum = 0, n = 0;
    for (auto v : m.vertices()) {
        for (auto w : m.vv_range(v)) {
            sum += static_cast<uint64_t>(w.idx());
            ++n;
        }
    }
    *count = n;
    return sum;
}

// Face and vertex normals (`update_normals`: each vertex the normalized
// sum of its faces' unit normals). Returns the sum of the vertex normals'
// x components, so that the work is not optimized away.
double raymesh_om_normals(void* mp) {
    Mesh& m = *static_cast<Mesh*>(mp);
    m.request_face_normals();
    m.request_vertex_normals();
    m.update_normals();
    double s = 0.0;
    for (auto v : m.vertices()) s += m.normal(v)[0];
    return s;
}

// One Loop step on a copy of the mesh: the nanoseconds the subdivision
// took (the copy not counted), the copy's faces afterwards in `*faces`.
uint64_t raymesh_om_loop(const void* mp, size_t* faces) {
    Mesh copy = *static_cast<const Mesh*>(mp);
    OpenMesh::Subdivider::Uniform::LoopT<Mesh> loop;
    auto start = std::chrono::steady_clock::now();
    loop.attach(copy);
    loop(1);
    loop.detach();
    auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::steady_clock::now() - start).count();
    *faces = copy.n_faces();
    return static_cast<uint64_t>(ns);
}

}  // extern "C"
