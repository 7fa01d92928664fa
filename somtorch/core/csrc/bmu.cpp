// Fused best-matching-unit search for somtorch (see somtorch/core/native.py).
//
// For every member e and sample n: the index of the smallest exact squared distance
//     dist(n, k) = (x_0 - w_k0)^2 + (x_1 - w_k1)^2 + ... + (x_{D-1} - w_k,D-1)^2
// summed left to right in the input precision, first index on ties (like torch.argmin); with
// top2 also the second smallest (ties again by index). No N x E x K score matrix is ever held.
//
// Vectorised over samples: a tile holds U vectors of W samples (transposed to feature-major),
// every neuron's features are broadcast and each lane keeps its own running minimum, so no
// horizontal reduction is needed. Built with -ffp-contract=off: every lane performs the same
// IEEE operations in the same order as the scalar formula above, hence the result of a sample
// does not depend on its lane, tile, thread, the number of threads, or the other members.
//
// Plain C ABI (called through ctypes); no torch headers, so it builds in about a second.
// OpenMP comes from the libgomp that torch has already loaded (same soname), so it shares
// torch's thread pool.

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

typedef float f32x8 __attribute__((vector_size(32)));
typedef int32_t i32x8 __attribute__((vector_size(32)));
typedef double f64x4 __attribute__((vector_size(32)));
typedef int64_t i64x4 __attribute__((vector_size(32)));

template <typename T> struct Lanes;
template <> struct Lanes<float> {
  typedef f32x8 V;
  typedef i32x8 I;
  typedef int32_t Idx;
  static constexpr int W = 8;
};
template <> struct Lanes<double> {
  typedef f64x4 V;
  typedef i64x4 I;
  typedef int64_t Idx;
  static constexpr int W = 4;
};

constexpr int U = 2;  // vectors per tile (independent dependency chains)

// One tile (U*W samples, feature-major in xs[d * TW + lane]) against one member's weights
// w (K, D). DC > 0: D known at compile time (registers); DC == 0: runtime D (loads from L1).
template <typename T, int DC, bool TOP2>
inline void tile(const T* __restrict xs, const T* __restrict w, int64_t K, int64_t D,
                 typename Lanes<T>::Idx* __restrict i1_out,
                 typename Lanes<T>::Idx* __restrict i2_out) {
  typedef typename Lanes<T>::V V;
  typedef typename Lanes<T>::I I;
  constexpr int W = Lanes<T>::W;
  constexpr int TW = U * W;
  const T inf = std::numeric_limits<T>::infinity();
  V b1[U], b2[U];
  I i1[U], i2[U];
  for (int u = 0; u < U; ++u) {
    b1[u] = V{} + inf;
    b2[u] = V{} + inf;
    i1[u] = I{};
    i2[u] = I{};
  }
  V xr[U][DC > 0 ? DC : 1];
  if (DC > 0) {
    for (int u = 0; u < U; ++u)
      for (int d = 0; d < DC; ++d) std::memcpy(&xr[u][d], xs + d * TW + u * W, sizeof(V));
  }
  for (int64_t k = 0; k < K; ++k) {
    const T* wk = w + k * (DC > 0 ? DC : D);
    const I kv = I{} + (typename Lanes<T>::Idx)k;
    for (int u = 0; u < U; ++u) {
      V acc;
      if (DC > 0) {
        V t = xr[u][0] - wk[0];
        acc = t * t;
        for (int d = 1; d < DC; ++d) {
          t = xr[u][d] - wk[d];
          acc = acc + t * t;
        }
      } else {
        V xv;
        std::memcpy(&xv, xs + u * W, sizeof(V));
        V t = xv - wk[0];
        acc = t * t;
        for (int64_t d = 1; d < D; ++d) {
          std::memcpy(&xv, xs + d * TW + u * W, sizeof(V));
          t = xv - wk[d];
          acc = acc + t * t;
        }
      }
      const I m1 = acc < b1[u];
      if (TOP2) {
        const I m2 = acc < b2[u];
        b2[u] = m1 ? b1[u] : (m2 ? acc : b2[u]);
        i2[u] = m1 ? i1[u] : (m2 ? kv : i2[u]);
      }
      b1[u] = m1 ? acc : b1[u];
      i1[u] = m1 ? kv : i1[u];
    }
  }
  for (int u = 0; u < U; ++u) {
    std::memcpy(i1_out + u * W, &i1[u], sizeof(I));
    if (TOP2) std::memcpy(i2_out + u * W, &i2[u], sizeof(I));
  }
}

// Rows xe[0 .. nv) of a (., D) array into the feature-major tile xs[d * TW + lane]; padded lanes
// repeat the last sample (their results are discarded).
template <typename T, int DC>
inline void load_tile(const T* __restrict xe, int64_t nv, int64_t D, T* __restrict xs) {
  constexpr int TW = U * Lanes<T>::W;
  if (DC > 0 && nv == TW) {
    for (int j = 0; j < TW; ++j)
      for (int d = 0; d < DC; ++d) xs[d * TW + j] = xe[j * DC + d];
  } else {
    for (int64_t j = 0; j < TW; ++j) {
      const T* row = xe + (j < nv ? j : nv - 1) * D;
      for (int64_t d = 0; d < D; ++d) xs[d * TW + j] = row[d];
    }
  }
}

constexpr double kMinWorkPerThread = 1048576.0;  // E·N·K·D terms (~0.2 ms): less is not worth a fork

inline int clamp_threads(int nthreads, double work, int64_t items) {
  if (nthreads < 1 || work < kMinWorkPerThread) nthreads = 1;
  if (items < nthreads) nthreads = (int)items;
  return nthreads;
}

// Items per dynamically scheduled chunk: about 1/16 of kMinWorkPerThread each. Dynamic, not
// static, so that a thread the OS has descheduled (a busy 2-core machine) does not leave its
// fixed share waiting; which thread computes an item never changes its result.
inline int64_t chunk_items(double work_per_item) {
  const double c = kMinWorkPerThread / 16.0 / (work_per_item > 1.0 ? work_per_item : 1.0);
  return c < 1.0 ? 1 : (int64_t)c;
}

// x: (N, D) shared (x_stride == 0) or (E, N, D) with x_stride == N * D; w: (E, K, D);
// out: (E, N) int64, or (E, N, 2) when TOP2.
template <typename T, int DC, bool TOP2>
void run(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
         int64_t* out, int nthreads) {
  typedef typename Lanes<T>::Idx Idx;
  constexpr int TW = U * Lanes<T>::W;
  const int64_t tiles = (N + TW - 1) / TW;
  const bool shared = x_stride == 0;
  const int64_t items = shared ? tiles : E * tiles;  // shared x: an item is one tile, all members
  nthreads = clamp_threads(nthreads, (double)E * (double)N * (double)K * (double)D, items);
  const int64_t chunk = chunk_items((double)(shared ? E : 1) * TW * (double)K * (double)D);
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    std::vector<T> xs_buf((size_t)D * TW);
    T* xs = xs_buf.data();
    alignas(32) Idx i1[TW];
    alignas(32) Idx i2[TW];
#pragma omp for schedule(dynamic, chunk)
    for (int64_t item = 0; item < items; ++item) {
      const int64_t e0 = shared ? 0 : item / tiles;
      const int64_t t = shared ? item : item % tiles;
      const int64_t n0 = t * TW;
      const int64_t nv = N - n0 < TW ? N - n0 : TW;
      load_tile<T, DC>(x + e0 * x_stride + n0 * D, nv, D, xs);
      const int64_t e_end = shared ? E : e0 + 1;
      for (int64_t e = e0; e < e_end; ++e) {
        tile<T, DC, TOP2>(xs, w + e * K * D, K, D, i1, i2);
        if (TOP2) {
          int64_t* o = out + (e * N + n0) * 2;
          for (int64_t j = 0; j < nv; ++j) {
            o[2 * j] = i1[j];
            o[2 * j + 1] = i2[j];
          }
        } else {
          int64_t* o = out + e * N + n0;
          for (int64_t j = 0; j < nv; ++j) o[j] = i1[j];
        }
      }
    }
  }
}

// Batch-map statistics: sums (E, K, D) += x_n and counts (E, K) += 1 over the samples each unit
// wins (both zero on entry). Parallel over members only, and each member's sums are added in
// sample order (as torch's index_add_ does), so the result does not depend on the thread count
// and member e equals a solo map.
template <typename T, int DC>
void run_acc(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
             T* sums, int64_t* counts, int nthreads) {
  typedef typename Lanes<T>::Idx Idx;
  constexpr int TW = U * Lanes<T>::W;
  const int64_t tiles = (N + TW - 1) / TW;
  const bool shared = x_stride == 0;
  nthreads = clamp_threads(nthreads, (double)E * (double)N * (double)K * (double)D, (E + 3) / 4);
  std::vector<T> xt;  // shared x: all tiles transposed once, tile t at xt[t * D * TW]
  if (shared) {
    xt.resize((size_t)(tiles * D * TW));
    for (int64_t t = 0; t < tiles; ++t)
      load_tile<T, DC>(x + t * TW * D, N - t * TW < TW ? N - t * TW : TW, D, xt.data() + t * D * TW);
  }
  // Members are taken G at a time and their sums interleaved sample by sample: each member's (and
  // each unit's) additions stay in sample order, but the G chains of dependent adds — long ones on
  // spatially coherent data, where neighbours share a unit — overlap instead of waiting on each other.
  constexpr int64_t G = 4;
  const int64_t groups = (E + G - 1) / G;
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    std::vector<T> xs_buf(shared ? 0 : (size_t)D * TW);
    alignas(32) Idx i1[G][TW];
#pragma omp for schedule(dynamic, 1)
    for (int64_t grp = 0; grp < groups; ++grp) {
      const int64_t e0 = grp * G;
      const int64_t ge = E - e0 < G ? E - e0 : G;
      for (int64_t t = 0; t < tiles; ++t) {
        const int64_t n0 = t * TW;
        const int64_t nv = N - n0 < TW ? N - n0 : TW;
        for (int64_t g = 0; g < ge; ++g) {
          const int64_t e = e0 + g;
          const T* xs = xt.data() + t * D * TW;
          if (!shared) {
            load_tile<T, DC>(x + e * x_stride + n0 * D, nv, D, xs_buf.data());
            xs = xs_buf.data();
          }
          tile<T, DC, false>(xs, w + e * K * D, K, D, i1[g], nullptr);
        }
        // Two copies on purpose: with the constant G the member loop unrolls; a generic lambda taking
        // std::integral_constant was measured 7 % slower on the E=100 batch epoch (43.3 vs 40.6 ms).
        if (ge == G) {
          for (int64_t j = 0; j < nv; ++j) {
            for (int64_t g = 0; g < G; ++g) {
              const int64_t e = e0 + g;
              const int64_t k = i1[g][j];
              const T* row = x + e * x_stride + (n0 + j) * D;
              T* sk = sums + (e * K + k) * D;
              for (int64_t d = 0; d < (DC > 0 ? DC : D); ++d) sk[d] += row[d];
              counts[e * K + k] += 1;
            }
          }
        } else {
          for (int64_t j = 0; j < nv; ++j) {
            for (int64_t g = 0; g < ge; ++g) {
              const int64_t e = e0 + g;
              const int64_t k = i1[g][j];
              const T* row = x + e * x_stride + (n0 + j) * D;
              T* sk = sums + (e * K + k) * D;
              for (int64_t d = 0; d < (DC > 0 ? DC : D); ++d) sk[d] += row[d];
              counts[e * K + k] += 1;
            }
          }
        }
      }
    }
  }
}

template <typename T>
void dispatch_acc(const T* x, int64_t xs, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
                  T* sums, int64_t* counts, int nt) {
  switch (D) {
    case 1: run_acc<T, 1>(x, xs, w, E, N, K, D, sums, counts, nt); break;
    case 2: run_acc<T, 2>(x, xs, w, E, N, K, D, sums, counts, nt); break;
    case 3: run_acc<T, 3>(x, xs, w, E, N, K, D, sums, counts, nt); break;
    case 4: run_acc<T, 4>(x, xs, w, E, N, K, D, sums, counts, nt); break;
    default: run_acc<T, 0>(x, xs, w, E, N, K, D, sums, counts, nt); break;
  }
}

// NaN weights would never win here but do win in torch.argmin: leave those calls to torch (2).
template <typename T>
bool has_nan(const T* w, int64_t count) {
  bool nan = false;
  for (int64_t i = 0; i < count; ++i) nan |= w[i] != w[i];
  return nan;
}

template <typename T>
int entry_acc(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
              T* sums, int64_t* counts, int nthreads) {
  if (E < 1 || N < 0 || K < 1 || D < 1) return 1;
  if (K > (int64_t)std::numeric_limits<typename Lanes<T>::Idx>::max()) return 1;
  if (has_nan(w, E * K * D)) return 2;
  if (N == 0) return 0;
  dispatch_acc<T>(x, x_stride, w, E, N, K, D, sums, counts, nthreads);
  return 0;
}

template <typename T, bool TOP2>
void dispatch_d(const T* x, int64_t xs, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
                int64_t* out, int nt) {
  switch (D) {
    case 1: run<T, 1, TOP2>(x, xs, w, E, N, K, D, out, nt); break;
    case 2: run<T, 2, TOP2>(x, xs, w, E, N, K, D, out, nt); break;
    case 3: run<T, 3, TOP2>(x, xs, w, E, N, K, D, out, nt); break;
    case 4: run<T, 4, TOP2>(x, xs, w, E, N, K, D, out, nt); break;
    default: run<T, 0, TOP2>(x, xs, w, E, N, K, D, out, nt); break;
  }
}

template <typename T>
int entry(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
          int top, int64_t* out, int nthreads) {
  if (E < 1 || N < 0 || K < 1 || D < 1 || (top != 1 && top != 2) || (top == 2 && K < 2)) return 1;
  if (K > (int64_t)std::numeric_limits<typename Lanes<T>::Idx>::max()) return 1;
  if (has_nan(w, E * K * D)) return 2;
  if (N == 0) return 0;
  if (top == 2)
    dispatch_d<T, true>(x, x_stride, w, E, N, K, D, out, nthreads);
  else
    dispatch_d<T, false>(x, x_stride, w, E, N, K, D, out, nthreads);
  return 0;
}

// Kohonen's online rule with a gaussian neighbourhood: S consecutive steps for each of E members,
// in place on w (E, K, D). Step s of member e, with its sample x = xs[e * xs_stride + s * D]:
//     c   = argmin_k sum_d (x_d - w_kd)^2          (first index on ties)
//     h_k = exp(log_lr[s, e] + g[c, k] * coef[s, e])   (coef = -1 / (2 sigma^2), g = grid d^2)
//     w_k = w_k + h_k * (x - w_k)
// the operations of somtorch.core.training.online_block in the same precision and order (the
// exponential is the C library's, so results agree with the torch path to rounding, not bits).
// Members are independent: threads take whole members, so member e equals a solo map bitwise.
template <typename T, int DC>
void run_online(T* w, const T* xs, int64_t xs_stride, const T* coef, const T* log_lr, const T* g,
                int64_t E, int64_t S, int64_t K, int64_t D, int nthreads) {
  nthreads = clamp_threads(nthreads, (double)E * (double)S * (double)K * (double)D * 16.0, E);
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    const int64_t DD = DC > 0 ? DC : D;
    std::vector<T> diff_buf((size_t)(K * DD)), h_buf((size_t)K);
    T* __restrict diff = diff_buf.data();
    T* __restrict h = h_buf.data();
#pragma omp for schedule(dynamic, 1)
    for (int64_t e = 0; e < E; ++e) {
      T* __restrict we = w + e * K * DD;
      const T* xe = xs + e * xs_stride;
      for (int64_t s = 0; s < S; ++s) {
        const T* x = xe + s * DD;
        int64_t c = 0;
        T best = std::numeric_limits<T>::infinity();
        for (int64_t k = 0; k < K; ++k) {
          T acc = 0;
          for (int64_t d = 0; d < DD; ++d) {
            const T v = x[d] - we[k * DD + d];
            diff[k * DD + d] = v;
            acc = acc + v * v;
          }
          if (acc < best) {
            best = acc;
            c = k;
          }
        }
        const T a = log_lr[s * E + e], b = coef[s * E + e];
        const T* gc = g + c * K;
        for (int64_t k = 0; k < K; ++k) h[k] = std::exp(a + gc[k] * b);
        for (int64_t k = 0; k < K; ++k)
          for (int64_t d = 0; d < DD; ++d) we[k * DD + d] = we[k * DD + d] + h[k] * diff[k * DD + d];
      }
    }
  }
}

template <typename T>
int entry_online(T* w, const T* xs, int64_t xs_stride, const T* coef, const T* log_lr, const T* g,
                 int64_t E, int64_t S, int64_t K, int64_t D, int nthreads) {
  if (E < 1 || S < 0 || K < 1 || D < 1) return 1;
  if (has_nan(w, E * K * D)) return 2;
  if (S == 0) return 0;
  switch (D) {
    case 1: run_online<T, 1>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads); break;
    case 2: run_online<T, 2>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads); break;
    case 3: run_online<T, 3>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads); break;
    case 4: run_online<T, 4>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads); break;
    default: run_online<T, 0>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads); break;
  }
  return 0;
}

// Bounded batch-map statistics (Hamerly's exact k-means bounds, across epochs): for member e and
// sample n with state c (its BMU), u >= distance to c and l <= distance to every other unit,
// after the weights moved by drift (E, K) (max dmax (E,)):
//     u += drift[e, c];  l -= dmax[e]           (both rounded outwards)
//     if not u (1 + rho) + alpha < l (1 - rho): search again (top 2, the tile kernel above, so the
//         BMU is bitwise the unbounded one), u = dist(c) (1 + grow), l = dist(c2) (1 - grow)
//     sums[e, c] += x_n, counts[e, c] += 1       (sample order, as run_acc)
// fresh != 0 searches every sample. searched[e] = how many samples member e searched. Threads take
// whole members, so member e equals a solo map bitwise.
template <typename T, int DC>
void run_bounded(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
                 int64_t* c, double* u, double* l, const double* drift, const double* dmax, double rho,
                 double alpha, double grow, int fresh, T* sums, int64_t* counts, int64_t* searched,
                 int nthreads) {
  typedef typename Lanes<T>::Idx Idx;
  constexpr int TW = U * Lanes<T>::W;
  const int64_t DD = DC > 0 ? DC : D;
  nthreads = clamp_threads(nthreads, (double)E * (double)N * (double)K * (double)D, E);
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    std::vector<T> xs_buf((size_t)D * TW);
    std::vector<T> rows((size_t)D * TW);
    std::vector<int64_t> redo;
    alignas(32) Idx i1[TW];
    alignas(32) Idx i2[TW];
#pragma omp for schedule(dynamic, 1)
    for (int64_t e = 0; e < E; ++e) {
      const T* xe = x + e * x_stride;
      const T* we = w + e * K * DD;
      int64_t* ce = c + e * N;
      double* ue = u + e * N;
      double* le = l + e * N;
      redo.clear();
      if (fresh) {
        redo.resize((size_t)N);
        for (int64_t n = 0; n < N; ++n) redo[(size_t)n] = n;
      } else {
        const double* de = drift + e * K;
        const double up = 1.0 + 2.0 * std::numeric_limits<double>::epsilon();
        const double down = 1.0 - 2.0 * std::numeric_limits<double>::epsilon();
        for (int64_t n = 0; n < N; ++n) {
          const double un = (ue[n] + de[ce[n]]) * up;
          const double ln = (le[n] - dmax[e]) * down;
          ue[n] = un;
          le[n] = ln;
          if (!(un * (1.0 + rho) + alpha < ln * (1.0 - rho))) redo.push_back(n);
        }
      }
      searched[e] = (int64_t)redo.size();
      const int64_t R = (int64_t)redo.size();
      for (int64_t r0 = 0; r0 < R; r0 += TW) {
        const int64_t nv = R - r0 < TW ? R - r0 : TW;
        for (int64_t j = 0; j < TW; ++j) {  // the rows of this tile, gathered
          const T* row = xe + redo[(size_t)(r0 + (j < nv ? j : nv - 1))] * DD;
          for (int64_t d = 0; d < DD; ++d) rows[(size_t)(j * DD + d)] = row[d];
        }
        load_tile<T, DC>(rows.data(), nv, D, xs_buf.data());
        tile<T, DC, true>(xs_buf.data(), we, K, D, i1, i2);
        for (int64_t j = 0; j < nv; ++j) {
          const int64_t n = redo[(size_t)(r0 + j)];
          const T* xn = xe + n * DD;
          const T* w1 = we + (int64_t)i1[j] * DD;
          const T* w2 = we + (int64_t)i2[j] * DD;
          T s1 = 0, s2 = 0;
          for (int64_t d = 0; d < DD; ++d) {
            const T t1 = xn[d] - w1[d], t2 = xn[d] - w2[d];
            s1 = s1 + t1 * t1;
            s2 = s2 + t2 * t2;
          }
          ce[n] = i1[j];
          ue[n] = std::sqrt((double)s1 * (1.0 + grow));
          le[n] = std::sqrt((double)s2 * (1.0 - grow));
        }
      }
      T* se = sums + e * K * DD;
      int64_t* ke = counts + e * K;
      for (int64_t n = 0; n < N; ++n) {
        const int64_t k = ce[n];
        const T* row = xe + n * DD;
        T* sk = se + k * DD;
        for (int64_t d = 0; d < DD; ++d) sk[d] += row[d];
        ke[k] += 1;
      }
    }
  }
}

template <typename T>
int entry_bounded(const T* x, int64_t x_stride, const T* w, int64_t E, int64_t N, int64_t K, int64_t D,
                  int64_t* c, double* u, double* l, const double* drift, const double* dmax, double rho,
                  double alpha, double grow, int fresh, T* sums, int64_t* counts, int64_t* searched,
                  int nthreads) {
  if (E < 1 || N < 0 || K < 2 || D < 1) return 1;
  if (K > (int64_t)std::numeric_limits<typename Lanes<T>::Idx>::max()) return 1;
  if (has_nan(w, E * K * D)) return 2;
  if (N == 0) return 0;
  switch (D) {
#define SOMTORCH_BOUNDED(DCV) \
    run_bounded<T, DCV>(x, x_stride, w, E, N, K, D, c, u, l, drift, dmax, rho, alpha, grow, fresh, sums, \
                        counts, searched, nthreads); \
    break;
    case 1: SOMTORCH_BOUNDED(1)
    case 2: SOMTORCH_BOUNDED(2)
    case 3: SOMTORCH_BOUNDED(3)
    case 4: SOMTORCH_BOUNDED(4)
    default: SOMTORCH_BOUNDED(0)
#undef SOMTORCH_BOUNDED
  }
  return 0;
}

}  // namespace

extern "C" {

// Version of this C ABI; native.py refuses a library that reports another one.
int somtorch_bmu_abi(void) { return 4; }

int somtorch_bmu_f32(const float* x, int64_t x_stride, const float* w, int64_t E, int64_t N,
                     int64_t K, int64_t D, int top, int64_t* out, int nthreads) {
  return entry<float>(x, x_stride, w, E, N, K, D, top, out, nthreads);
}

int somtorch_bmu_f64(const double* x, int64_t x_stride, const double* w, int64_t E, int64_t N,
                     int64_t K, int64_t D, int top, int64_t* out, int nthreads) {
  return entry<double>(x, x_stride, w, E, N, K, D, top, out, nthreads);
}

int somtorch_accumulate_f32(const float* x, int64_t x_stride, const float* w, int64_t E, int64_t N,
                            int64_t K, int64_t D, float* sums, int64_t* counts, int nthreads) {
  return entry_acc<float>(x, x_stride, w, E, N, K, D, sums, counts, nthreads);
}

int somtorch_accumulate_f64(const double* x, int64_t x_stride, const double* w, int64_t E,
                            int64_t N, int64_t K, int64_t D, double* sums, int64_t* counts,
                            int nthreads) {
  return entry_acc<double>(x, x_stride, w, E, N, K, D, sums, counts, nthreads);
}

int somtorch_online_f32(float* w, const float* xs, int64_t xs_stride, const float* coef,
                        const float* log_lr, const float* g, int64_t E, int64_t S, int64_t K,
                        int64_t D, int nthreads) {
  return entry_online<float>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads);
}

int somtorch_online_f64(double* w, const double* xs, int64_t xs_stride, const double* coef,
                        const double* log_lr, const double* g, int64_t E, int64_t S, int64_t K,
                        int64_t D, int nthreads) {
  return entry_online<double>(w, xs, xs_stride, coef, log_lr, g, E, S, K, D, nthreads);
}

int somtorch_bounded_f32(const float* x, int64_t x_stride, const float* w, int64_t E, int64_t N, int64_t K,
                         int64_t D, int64_t* c, double* u, double* l, const double* drift, const double* dmax,
                         double rho, double alpha, double grow, int fresh, float* sums, int64_t* counts,
                         int64_t* searched, int nthreads) {
  return entry_bounded<float>(x, x_stride, w, E, N, K, D, c, u, l, drift, dmax, rho, alpha, grow, fresh, sums,
                              counts, searched, nthreads);
}

int somtorch_bounded_f64(const double* x, int64_t x_stride, const double* w, int64_t E, int64_t N,
                         int64_t K, int64_t D, int64_t* c, double* u, double* l, const double* drift,
                         const double* dmax, double rho, double alpha, double grow, int fresh, double* sums,
                         int64_t* counts, int64_t* searched, int nthreads) {
  return entry_bounded<double>(x, x_stride, w, E, N, K, D, c, u, l, drift, dmax, rho, alpha, grow, fresh,
                               sums, counts, searched, nthreads);
}

}  // extern "C"
