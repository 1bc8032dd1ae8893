// Particle-grid transfers of MLS-MPM with quadratic B-splines, fused, for the CPU (diffstir.mpm.transfer).
//
// A particle p at `frac` (cells from its base node, in [0.5, 1.5) per axis) has the stencil nodes k = (i, j[, l]),
// first axis slowest, at flat indices index[p, k], with weights w_pk = N_i(f_0) N_j(f_1) [N_l(f_2)],
// N_0(f) = (1.5 - f)^2 / 2, N_1(f) = 3/4 - (f - 1)^2, N_2(f) = (f - 0.5)^2 / 2, and s_k = [o_k, 1] the node's
// offset with a trailing one. Component-major particle arrays P (C, N, d + 1), node arrays G (nodes, C).
//
//   scatter:   G[i, c]    = sum_{p,k: index[p,k] = i} w_pk (P[c, p, :] . s_k)
//   gather:    P[c, p, :] = sum_k w_pk G[index[p, k], c] s_k
//   frac_grad: D[p, a]    = sum_k (d w_pk / d f_a) sum_c G[index[p, k], c] (P[c, p, :] . s_k)
//
// scatter and gather are adjoint; frac_grad is the derivative of either through the weights (reverse mode). With a
// tangent dfrac, scatter and gather use the weights' directional derivatives sum_a (d w_pk / d f_a) dfrac[p, a]
// in place of the weights (forward mode).

#include <torch/extension.h>

namespace {

constexpr int MAX_COLUMNS = 8;

template <typename T>
inline void bspline(T f, T* w, T* dw) {
  w[0] = T(0.5) * (T(1.5) - f) * (T(1.5) - f);
  w[1] = T(0.75) - (f - T(1)) * (f - T(1));
  w[2] = T(0.5) * (f - T(0.5)) * (f - T(0.5));
  dw[0] = f - T(1.5);
  dw[1] = T(-2) * (f - T(1));
  dw[2] = f - T(0.5);
}

// d w / d f_a at the node of offset o: the derivative of axis a's factor times the other axes' factors.
template <int D, typename T>
inline T weight_derivative(const T (*w)[3], const T (*dw)[3], const int* o, int a) {
  T value = dw[a][o[a]];
  for (int b = 0; b < D; ++b)
    if (b != a) value *= w[b][o[b]];
  return value;
}

// Calls body(k, o, weight) for each stencil node k, offset o (d ints), of the particle at frac: weight is w_pk, or
// with a Tangent dfrac its directional derivative; it fills w (d x 3) with the per-axis factors and dw with their
// derivatives.
template <int D, bool Tangent, typename T, typename Body>
inline void for_each_node(const T* frac, const T* dfrac, T (*w)[3], T (*dw)[3], Body body) {
  for (int a = 0; a < D; ++a) bspline(frac[a], w[a], dw[a]);
  int k = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int l = 0; l < (D == 3 ? 3 : 1); ++l) {
        const int o[3] = {i, j, l};
        T weight = w[0][i] * w[1][j];
        if constexpr (D == 3) weight *= w[2][l];
        if constexpr (Tangent) {
          weight = 0;
          for (int a = 0; a < D; ++a) weight += weight_derivative<D, T>(w, dw, o, a) * dfrac[a];
        }
        body(k++, o, weight);
      }
}

// A particle's stencil nodes increase with k (positive strides): its first and last must lie on the grid.
inline void check_particle(const int64_t* ip, int K, int64_t nodes) {
  TORCH_CHECK(ip[0] >= 0 && ip[K - 1] < nodes, "transfer: a stencil reaches node ", ip[0] < 0 ? ip[0] : ip[K - 1],
              ", off the grid of ", nodes, " nodes");
}

// value[k][c] = P[c, p, :] . s_k for the particle's 3^d nodes, by increments along the axes.
template <int D, int C, typename T>
inline void node_values(const T* P, int64_t p, int64_t N, T (*value)[C]) {
  for (int c = 0; c < C; ++c) {
    const T* row = P + (c * N + p) * (D + 1);
    int k = 0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const T ij = row[D] + T(i) * row[0] + T(j) * row[1];
        if constexpr (D == 2) {
          value[k++][c] = ij;
        } else {
          for (int l = 0; l < 3; ++l) value[k++][c] = ij + T(l) * row[2];
        }
      }
  }
}

// P[c, p, :] = sum_k value[k][c] s_k: the sum and first moments over the particle's 3^d nodes (a 3-D stencil's
// lines along its last axis summed first).
template <int D, int C, typename T>
inline void node_moments(const T (*value)[C], int64_t p, int64_t N, T* P) {
  for (int c = 0; c < C; ++c) {
    T moment[D + 1] = {};
    int k = 0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        T line = value[k][c];
        if constexpr (D == 3) {
          line += value[k + 1][c] + value[k + 2][c];
          moment[2] += value[k + 1][c] + T(2) * value[k + 2][c];
          k += 3;
        } else {
          ++k;
        }
        moment[0] += T(i) * line;
        moment[1] += T(j) * line;
        moment[D] += line;
      }
    for (int a = 0; a <= D; ++a) P[(c * N + p) * (D + 1) + a] = moment[a];
  }
}

template <int D, int C, bool Tangent, typename T>
void scatter_loop(const T* P, const T* frac, const T* dfrac, const int64_t* index, T* G, int64_t N, int64_t nodes) {
  constexpr int K = D == 3 ? 27 : 9;
  for (int64_t p = 0; p < N; ++p) {
    const int64_t* ip = index + p * K;
    check_particle(ip, K, nodes);
    T value[K][C];
    node_values<D, C>(P, p, N, value);
    T factors[D][3], slopes[D][3];
    for_each_node<D, Tangent>(frac + p * D, dfrac + p * D, factors, slopes, [&](int k, const int*, T w) {
      T* g = G + ip[k] * C;
      for (int c = 0; c < C; ++c) g[c] += w * value[k][c];
    });
  }
}

template <int D, int C, typename T>
void scatter_impl(const T* P, const T* frac, const T* dfrac, const int64_t* index, T* G, int64_t N, int64_t nodes) {
  if (dfrac) return scatter_loop<D, C, true>(P, frac, dfrac, index, G, N, nodes);
  scatter_loop<D, C, false>(P, frac, frac, index, G, N, nodes);
}

template <int D, int C, bool Tangent, typename T>
void gather_loop(const T* G, const T* frac, const T* dfrac, const int64_t* index, T* P, int64_t N, int64_t nodes) {
  constexpr int K = D == 3 ? 27 : 9;
  for (int64_t p = 0; p < N; ++p) {
    const int64_t* ip = index + p * K;
    check_particle(ip, K, nodes);
    T value[K][C];
    T factors[D][3], slopes[D][3];
    for_each_node<D, Tangent>(frac + p * D, dfrac + p * D, factors, slopes, [&](int k, const int*, T w) {
      const T* g = G + ip[k] * C;
      for (int c = 0; c < C; ++c) value[k][c] = w * g[c];
    });
    node_moments<D, C>(value, p, N, P);
  }
}

template <int D, int C, typename T>
void gather_impl(const T* G, const T* frac, const T* dfrac, const int64_t* index, T* P, int64_t N, int64_t nodes) {
  if (dfrac) return gather_loop<D, C, true>(G, frac, dfrac, index, P, N, nodes);
  gather_loop<D, C, false>(G, frac, frac, index, P, N, nodes);
}

template <int D, int C, typename T>
void frac_grad_impl(const T* G, const T* P, const T* frac, const int64_t* index, T* out, int64_t N, int64_t nodes) {
  constexpr int K = D == 3 ? 27 : 9;
  for (int64_t p = 0; p < N; ++p) {
    const int64_t* ip = index + p * K;
    check_particle(ip, K, nodes);
    T value[K][C];
    node_values<D, C>(P, p, N, value);
    T w[D][3], dw[D][3];
    T grad[D] = {};
    for_each_node<D, false>(frac + p * D, frac + p * D, w, dw, [&](int k, const int* o, T) {
      const T* g = G + ip[k] * C;
      T dL_dw = 0;
      for (int c = 0; c < C; ++c) dL_dw += g[c] * value[k][c];
      for (int a = 0; a < D; ++a) grad[a] += dL_dw * weight_derivative<D, T>(w, dw, o, a);
    });
    for (int a = 0; a < D; ++a) out[p * D + a] = grad[a];
  }
}

void check(const torch::Tensor& frac, const torch::Tensor& index, int64_t columns) {
  TORCH_CHECK(frac.device().is_cpu(), "transfer: the fused kernels run on the CPU");
  TORCH_CHECK(frac.dim() == 2 && (frac.size(1) == 2 || frac.size(1) == 3), "transfer: frac must be (N, 2 or 3)");
  const int64_t K = frac.size(1) == 3 ? 27 : 9;
  TORCH_CHECK(index.scalar_type() == torch::kInt64 && index.dim() == 2 && index.size(0) == frac.size(0) &&
                  index.size(1) == K, "transfer: index must be int64 (N, 3^d)");
  TORCH_CHECK(columns >= 1 && columns <= MAX_COLUMNS, "transfer: 1 to ", MAX_COLUMNS, " columns, got ", columns);
}

// run<Kernel>(d, columns, args...) calls Kernel<d, columns> for d in {2, 3} and 1 to MAX_COLUMNS columns.
template <template <int, int> class Kernel, int C = 1, typename... Args>
void run(int64_t D, int64_t columns, Args... args) {
  if constexpr (C <= MAX_COLUMNS) {
    if (columns != C) return run<Kernel, C + 1>(D, columns, args...);
    if (D == 3) return Kernel<3, C>::call(args...);
    return Kernel<2, C>::call(args...);
  }
}

template <int D, int C>
struct Scatter {
  template <typename... Args> static void call(Args... args) { scatter_impl<D, C>(args...); }
};
template <int D, int C>
struct Gather {
  template <typename... Args> static void call(Args... args) { gather_impl<D, C>(args...); }
};
template <int D, int C>
struct FracGrad {
  template <typename... Args> static void call(Args... args) { frac_grad_impl<D, C>(args...); }
};

}  // namespace

// A tangent, if given, must be like frac; its data pointer, or none.
template <typename T>
const T* tangent_data(const c10::optional<torch::Tensor>& dfrac, const torch::Tensor& frac) {
  if (!dfrac) return nullptr;
  TORCH_CHECK(dfrac->sizes() == frac.sizes() && dfrac->is_contiguous() &&
                  dfrac->scalar_type() == frac.scalar_type(), "transfer: dfrac must be a contiguous tensor like frac");
  return dfrac->data_ptr<T>();
}

torch::Tensor scatter(torch::Tensor particles, torch::Tensor frac, torch::Tensor index, int64_t nodes,
                      c10::optional<torch::Tensor> dfrac) {
  const int64_t C = particles.size(0), N = frac.size(0), D = frac.size(1);
  check(frac, index, C);
  TORCH_CHECK(particles.dim() == 3 && particles.size(1) == N && particles.size(2) == D + 1,
              "transfer: particle values must be (C, N, d + 1)");
  particles = particles.contiguous(), frac = frac.contiguous(), index = index.contiguous();
  auto grid = torch::zeros({nodes, C}, particles.options());
  AT_DISPATCH_FLOATING_TYPES(particles.scalar_type(), "scatter", [&] {
    run<Scatter>(D, C, particles.data_ptr<scalar_t>(), frac.data_ptr<scalar_t>(), tangent_data<scalar_t>(dfrac, frac),
                 index.data_ptr<int64_t>(), grid.data_ptr<scalar_t>(), N, nodes);
  });
  return grid;
}

torch::Tensor gather(torch::Tensor grid, torch::Tensor frac, torch::Tensor index, c10::optional<torch::Tensor> dfrac) {
  const int64_t C = grid.size(1), N = frac.size(0), D = frac.size(1);
  check(frac, index, C);
  grid = grid.contiguous(), frac = frac.contiguous(), index = index.contiguous();
  auto particles = torch::empty({C, N, D + 1}, grid.options());
  AT_DISPATCH_FLOATING_TYPES(grid.scalar_type(), "gather", [&] {
    run<Gather>(D, C, grid.data_ptr<scalar_t>(), frac.data_ptr<scalar_t>(), tangent_data<scalar_t>(dfrac, frac),
                index.data_ptr<int64_t>(), particles.data_ptr<scalar_t>(), N, grid.size(0));
  });
  return particles;
}

torch::Tensor frac_grad(torch::Tensor grid, torch::Tensor particles, torch::Tensor frac, torch::Tensor index) {
  const int64_t C = grid.size(1), N = frac.size(0), D = frac.size(1);
  check(frac, index, C);
  TORCH_CHECK(particles.size(0) == C, "transfer: grid and particle values must have the same columns");
  grid = grid.contiguous(), particles = particles.contiguous(), frac = frac.contiguous(), index = index.contiguous();
  auto out = torch::empty({N, D}, frac.options());
  AT_DISPATCH_FLOATING_TYPES(grid.scalar_type(), "frac_grad", [&] {
    run<FracGrad>(D, C, grid.data_ptr<scalar_t>(), particles.data_ptr<scalar_t>(), frac.data_ptr<scalar_t>(),
                  index.data_ptr<int64_t>(), out.data_ptr<scalar_t>(), N, grid.size(0));
  });
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("scatter", &scatter, "particle values (C, N, d+1) to the grid (nodes, C); with dfrac, its tangent in frac",
        py::arg("particles"), py::arg("frac"), py::arg("index"), py::arg("nodes"), py::arg("dfrac") = py::none());
  m.def("gather", &gather, "grid values (nodes, C) to particle moments (C, N, d+1); with dfrac, its tangent in frac",
        py::arg("grid"), py::arg("frac"), py::arg("index"), py::arg("dfrac") = py::none());
  m.def("frac_grad", &frac_grad, "derivative of scatter or gather through the B-spline weights, (N, d)");
}
