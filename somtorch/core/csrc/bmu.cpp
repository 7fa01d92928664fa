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
// Also: somtorch_label_stats, the object step's one pass over a label map (counts, sums, boxes and
// the adjacency of 4-connected pixel pairs; see somtorch/core/label_stats.py), and
// somtorch_plane_counts, the ground fit's counts of each plane hypothesis over sampled pixels
// (inliers, in view, behind; see somtorch/core/plane_counts.py), and somtorch_plane_band, one
// plane's band and those counts over a whole map.
//
// Plain C ABI (called through ctypes); no torch headers, so it builds in about a second.
// OpenMP comes from the libgomp that torch has already loaded (same soname), so it shares
// torch's thread pool.

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif
#ifdef __AVX__
#include <immintrin.h>
#endif

namespace {

typedef float f32x8 __attribute__((vector_size(32)));
typedef int32_t i32x8 __attribute__((vector_size(32)));
typedef double f64x4 __attribute__((vector_size(32)));
typedef int64_t i64x4 __attribute__((vector_size(32)));

#if defined(__AVX512F__)
constexpr int kSearchBytes = 64;  // vector width of the search kernels: 16 float32 / 8 float64 lanes
#else
constexpr int kSearchBytes = 32;  // AVX2 (or SSE, split by the compiler): 8 float32 / 4 float64 lanes
#endif

// Vector types of a kernel: W lanes of T, and the lane indices (int32 for float, int64 for double).
template <typename T, int Bytes = kSearchBytes>
struct Lanes {
  typedef T V __attribute__((vector_size(Bytes)));
  typedef typename std::conditional<sizeof(T) == 4, int32_t, int64_t>::type Idx;
  typedef Idx I __attribute__((vector_size(Bytes)));
  static constexpr int W = Bytes / (int)sizeof(T);
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
  // D = 3: each unit's sums and count packed in one 4-lane vector (s0, s1, s2, n), updated by one
  // vector add of (x0, x1, x2, 1) per sample: the same IEEE additions per lane, in sample order, and
  // the count exact while N < 2^24 (float32; 2^53 float64).
  typedef typename Lanes<T, 4 * sizeof(T)>::V V4;
  const bool pack = DC == 3 && (double)N < (sizeof(T) == 4 ? 16777216.0 : 9007199254740992.0);
  std::vector<V4> xpad(pack ? (size_t)((shared ? 1 : E) * N) : 0), acc(pack ? (size_t)(E * K) : 0);
  for (int64_t i = 0; i < (int64_t)xpad.size(); ++i) {
    const T* r = x + i * 3;  // (E, N, 3) and (N, 3) rows alike: x_stride == N * 3
    xpad[(size_t)i] = V4{r[0], r[1], r[2], (T)1};
  }
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    std::vector<T> xs_buf(shared ? 0 : (size_t)D * TW);
    alignas(64) Idx i1[G][TW];
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
        if (pack) {
          for (int64_t j = 0; j < nv; ++j) {
            for (int64_t g = 0; g < ge; ++g) {
              const int64_t e = e0 + g;
              V4* a = acc.data() + e * K + i1[g][j];
              *a = *a + xpad[(size_t)((shared ? 0 : e * N) + n0 + j)];
            }
          }
        } else if (ge == G) {
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
  for (int64_t i = 0; i < (int64_t)acc.size(); ++i) {
    for (int d = 0; d < 3; ++d) sums[i * 3 + d] = acc[(size_t)i][d];
    counts[i] = (int64_t)acc[(size_t)i][3];
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
// in place on w (E, K, D). Step s of member e uses the sample x = data[e * x_stride + i * D] with
// i = idx[e * idx_stride + s] (x_stride = 0: data shared; idx_stride = 0: one order for all):
//     c   = argmin_k sum_d (x_d - w_kd)^2          (first index on ties)
//     h_k = exp(log_lr[s, e] + g[c, k] * coef[s, e])   (coef = -1 / (2 sigma^2), g = grid d^2)
//     w_k = w_k + h_k * (x - w_k)
// the operations of somtorch.core.training.online_block in the same precision and order (the
// exponential is the C library's, so results agree with the torch path to rounding, not bits).
// Two layouts compute the same bits: run_online (one member at a time, for E < kLaneMembers) and
// run_online_lanes (W members in the lanes of one vector); either way member e equals a solo map.
template <typename T, int DC>
void run_online(T* w, const T* data, int64_t x_stride, const int64_t* idx, int64_t idx_stride,
                const T* coef, const T* log_lr, const T* g, int64_t E, int64_t S, int64_t K, int64_t D,
                int nthreads) {
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
      const T* xe = data + e * x_stride;
      const int64_t* ie = idx + e * idx_stride;
      for (int64_t s = 0; s < S; ++s) {
        const T* x = xe + ie[s] * DD;
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

constexpr int64_t kLaneMembers = 2;     // ensembles from this size run members in vector lanes
constexpr int64_t kTableMaxK = 1024;    // larger maps compute h per lane (no K x K table per thread)
constexpr int64_t kAhead = 4;          // steps ahead whose samples are prefetched

// h[j][l] = rows[l][j] for j < W: W consecutive entries of W rows (one per lane) turned into W vectors.
template <typename T>
inline void transpose_rows(const T* const* rows, typename Lanes<T, 32>::V* h) {
  for (int j = 0; j < Lanes<T, 32>::W; ++j)
    for (int l = 0; l < Lanes<T, 32>::W; ++l) h[j][l] = rows[l][j];
}
#ifdef __AVX__
template <>
inline void transpose_rows<float>(const float* const* rows, f32x8* h) {
  __m256 r[8], t[8], q[8];
  for (int l = 0; l < 8; ++l) r[l] = _mm256_loadu_ps(rows[l]);
  for (int l = 0; l < 8; l += 2) {
    t[l] = _mm256_unpacklo_ps(r[l], r[l + 1]);
    t[l + 1] = _mm256_unpackhi_ps(r[l], r[l + 1]);
  }
  for (int l = 0; l < 8; l += 4) {
    q[l] = _mm256_shuffle_ps(t[l], t[l + 2], 0x44);
    q[l + 1] = _mm256_shuffle_ps(t[l], t[l + 2], 0xEE);
    q[l + 2] = _mm256_shuffle_ps(t[l + 1], t[l + 3], 0x44);
    q[l + 3] = _mm256_shuffle_ps(t[l + 1], t[l + 3], 0xEE);
  }
  for (int j = 0; j < 4; ++j) {
    h[j] = (f32x8)_mm256_permute2f128_ps(q[j], q[j + 4], 0x20);
    h[j + 4] = (f32x8)_mm256_permute2f128_ps(q[j], q[j + 4], 0x31);
  }
}
template <>
inline void transpose_rows<double>(const double* const* rows, f64x4* h) {
  const __m256d r0 = _mm256_loadu_pd(rows[0]), r1 = _mm256_loadu_pd(rows[1]);
  const __m256d r2 = _mm256_loadu_pd(rows[2]), r3 = _mm256_loadu_pd(rows[3]);
  const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
  const __m256d t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
  h[0] = (f64x4)_mm256_permute2f128_pd(t0, t2, 0x20);
  h[1] = (f64x4)_mm256_permute2f128_pd(t1, t3, 0x20);
  h[2] = (f64x4)_mm256_permute2f128_pd(t0, t2, 0x31);
  h[3] = (f64x4)_mm256_permute2f128_pd(t1, t3, 0x31);
}
#endif

template <typename T>
inline bool same_bits(T a, T b) { return std::memcmp(&a, &b, sizeof(T)) == 0; }

// The distinct values of g (K*K entries, compared by bit pattern): vals, and vidx[i] with
// vals[vidx[i]] == g[i] bitwise. A grid has few (21 for 4 x 7, 120 for 16 x 16), so when every member
// of a step has the same log_lr and coef, one exp per distinct value serves them all and each h_k is
// exp(a + vals[v] * b) with the very operands of exp(a + g[c, k] * b): the same bits as run_online.
template <typename T>
void distinct_values(const T* g, int64_t n, std::vector<T>& vals, std::vector<int32_t>& vidx) {
  vals.clear();
  vidx.resize((size_t)n);
  size_t cap = 64;
  std::vector<int32_t> slot(cap, -1);
  auto hash = [](T v) {
    uint64_t u = 0;
    std::memcpy(&u, &v, sizeof(T));
    return (size_t)((u * 0x9E3779B97F4A7C15ull) >> 40);
  };
  for (int64_t i = 0; i < n; ++i) {
    size_t h = hash(g[i]) & (cap - 1);
    while (slot[h] >= 0 && !same_bits(vals[(size_t)slot[h]], g[i])) h = (h + 1) & (cap - 1);
    if (slot[h] < 0) {
      slot[h] = (int32_t)vals.size();
      vals.push_back(g[i]);
      if (2 * vals.size() > cap) {  // grow and re-insert
        cap *= 4;
        slot.assign(cap, -1);
        for (size_t j = 0; j < vals.size(); ++j) {
          size_t q = hash(vals[j]) & (cap - 1);
          while (slot[q] >= 0) q = (q + 1) & (cap - 1);
          slot[q] = (int32_t)j;
        }
        h = hash(g[i]) & (cap - 1);
        while (!same_bits(vals[(size_t)slot[h]], g[i])) h = (h + 1) & (cap - 1);
      }
    }
    vidx[(size_t)i] = slot[h];
  }
}

// What one thread's lane_step needs besides the blocks (see run_online_lanes).
template <typename T>
struct LaneStep {
  const T* data;
  int64_t x_stride;
  const int64_t* idx;
  int64_t idx_stride;
  const T* g;
  const T* lr_s;  // log_lr and coef of this step, (E,)
  const T* cf_s;
  int64_t S, K, D;
  const int32_t* vidx;  // (K, K) index into vals
  const T* vals;
  int64_t KP;       // row stride of H and hl: K rounded up to W
  T* H;            // (K, KP) neighbourhood rows of this step, filled on demand
  T* tv;           // exp per distinct value, this step
  T* hl;           // (U, W, KP) per-lane rows when the members' schedules differ
  int64_t* row_at;  // step at which H row c / tv[v] was last filled
  int64_t* val_at;
  bool eager;                         // tv holds every distinct value's exp for this step
  typename Lanes<T, 32>::V* xv_any;  // runtime D: scratch for U * D sample vectors
  T* xt_any;                          // runtime D: scratch for D * W scalars
};

// Step s of U consecutive blocks (wk: their (K, D) vectors, mem: the member of each lane).
template <typename T, int DC, int U>
inline void lane_step(const LaneStep<T>& st, int64_t s, bool shared, T a0, T c0, typename Lanes<T, 32>::V* wk,
                      const int64_t* mem) {
  typedef typename Lanes<T, 32>::V V;
  typedef typename Lanes<T, 32>::I I;
  typedef typename Lanes<T, 32>::Idx Idx;
  constexpr int W = Lanes<T, 32>::W;
  const int64_t K = st.K, DD = DC > 0 ? DC : st.D;
  V xloc[U][DC > 0 ? DC : 1];
  V* xv[U];
  for (int u = 0; u < U; ++u) {
    xv[u] = DC > 0 ? xloc[u] : st.xv_any + u * DD;
    alignas(64) T xt[DC > 0 ? DC : 1][W];
    T* xtp = DC > 0 ? &xt[0][0] : st.xt_any;
    for (int l = 0; l < W; ++l) {
      const int64_t e = mem[u * W + l];
      const int64_t* il = st.idx + e * st.idx_stride;
      const T* xl = st.data + e * st.x_stride;
      const T* xp = xl + il[s] * DD;
      for (int64_t d = 0; d < DD; ++d) xtp[d * W + l] = xp[d];
      if (s + kAhead < st.S) __builtin_prefetch(xl + il[s + kAhead] * DD);
    }
    for (int64_t d = 0; d < DD; ++d) std::memcpy(&xv[u][d], xtp + d * W, sizeof(V));
  }
  const T inf = std::numeric_limits<T>::infinity();
  V best[U];
  I c[U];
  for (int u = 0; u < U; ++u) {
    best[u] = V{} + inf;
    c[u] = I{};
  }
  for (int64_t k = 0; k < K; ++k) {
    const I kv = I{} + (Idx)k;
    for (int u = 0; u < U; ++u) {
      const V* wr = wk + (u * K + k) * DD;
      V t = xv[u][0] - wr[0];
      V acc = t * t;
      for (int64_t d = 1; d < DD; ++d) {
        t = xv[u][d] - wr[d];
        acc = acc + t * t;
      }
      const I m = acc < best[u];
      best[u] = m ? acc : best[u];
      c[u] = m ? kv : c[u];
    }
  }
  const T* rows[U][W];  // the neighbourhood row of each lane
  for (int u = 0; u < U; ++u) {
    if (shared) {
      for (int l = 0; l < W; ++l) {
        const int64_t cl = c[u][l];
        if (st.row_at[cl] == s) continue;
        st.row_at[cl] = s;
        const int32_t* vr = st.vidx + cl * K;
        T* hr = st.H + cl * st.KP;
        if (st.eager) {  // every tv[v] of this step is ready
          for (int64_t k = 0; k < K; ++k) hr[k] = st.tv[vr[k]];
          continue;
        }
        for (int64_t k = 0; k < K; ++k) {
          const int32_t v = vr[k];
          if (st.val_at[v] != s) {
            st.val_at[v] = s;
            st.tv[v] = std::exp(a0 + st.vals[v] * c0);
          }
          hr[k] = st.tv[v];
        }
      }
      for (int l = 0; l < W; ++l) rows[u][l] = st.H + (int64_t)c[u][l] * st.KP;
    } else {
      for (int l = 0; l < W; ++l) {
        const int64_t e = mem[u * W + l];
        const T a = st.lr_s[e], b = st.cf_s[e];
        const T* gc = st.g + (int64_t)c[u][l] * K;
        T* hr = st.hl + (u * W + l) * st.KP;
        for (int64_t k = 0; k < K; ++k) hr[k] = std::exp(a + gc[k] * b);
        rows[u][l] = hr;
      }
    }
  }
  // W entries of the W rows at a time, transposed in registers (a gather per k is ~3x slower here)
  for (int64_t k0 = 0; k0 < K; k0 += W) {
    const int64_t kn = K - k0 < W ? K - k0 : W;
    for (int u = 0; u < U; ++u) {
      const T* rk[W];
      for (int l = 0; l < W; ++l) rk[l] = rows[u][l] + k0;
      V h[W];
      transpose_rows<T>(rk, h);
      for (int64_t j = 0; j < kn; ++j) {
        V* wr = wk + (u * K + k0 + j) * DD;
        for (int64_t d = 0; d < DD; ++d) {
          const V wv = wr[d];
          wr[d] = wv + h[j] * (xv[u][d] - wv);
        }
      }
    }
  }
}

// The online rule with W members in the lanes of one vector (8 float32 / 4 float64 with AVX2):
// weights held as blocks (K, D, W), so one vector operation advances W members by the same scalar
// operation of run_online, lane by lane (-ffp-contract=off: no fused multiply-add), and the argmin
// keeps each lane's first index on ties through a strict compare and blend. Threads take contiguous
// ranges of blocks and walk the steps; in a step where the thread's members share log_lr and coef
// (one schedule for the ensemble) the neighbourhood rows h[c, :] are filled once from one exp per
// distinct grid distance and gathered per lane; otherwise each lane computes its own row.
template <typename T, int DC>
void run_online_lanes(T* w, const T* data, int64_t x_stride, const int64_t* idx, int64_t idx_stride,
                      const T* coef, const T* log_lr, const T* g, int64_t E, int64_t S, int64_t K,
                      int64_t D, int nthreads) {
  typedef typename Lanes<T, 32>::V V;
  typedef typename Lanes<T, 32>::I I;
  typedef typename Lanes<T, 32>::Idx Idx;
  constexpr int W = Lanes<T, 32>::W;
  const int64_t DD = DC > 0 ? DC : D;
  const int64_t B = (E + W - 1) / W;
  const bool table = K <= kTableMaxK;
  std::vector<T> vals;
  std::vector<int32_t> vidx;
  if (table) distinct_values(g, K * K, vals, vidx);
  const int64_t NV = (int64_t)vals.size();
  nthreads = clamp_threads(nthreads, (double)E * (double)S * (double)K * (double)D * 16.0, B);
#pragma omp parallel num_threads(nthreads) if (nthreads > 1)
  {
    int tid = 0, nt = 1;
#ifdef _OPENMP
    tid = omp_get_thread_num();
    nt = omp_get_num_threads();
#endif
    const int64_t b0 = B * tid / nt, b1 = B * (tid + 1) / nt, nb = b1 - b0;
    const int64_t e_lo = b0 * W, e_hi = b1 * W < E ? b1 * W : E;
    std::vector<V> wb_buf((size_t)(nb * K * DD));  // block j: (K, D) vectors at wb[j * K * DD]
    std::vector<int64_t> mem((size_t)(nb * W));    // member of each lane; padding repeats the last
    for (int64_t i = 0; i < nb * W; ++i) mem[(size_t)i] = e_lo + i < E ? e_lo + i : E - 1;
    V* __restrict wb = wb_buf.data();
    for (int64_t j = 0; j < nb; ++j)
      for (int l = 0; l < W; ++l) {
        const T* src = w + mem[(size_t)(j * W + l)] * K * DD;
        for (int64_t i = 0; i < K * DD; ++i) wb[j * K * DD + i][l] = src[i];
      }
    const int64_t KP = (K + W - 1) / W * W;
    std::vector<T> H(table && nb > 0 ? (size_t)(K * KP) : 0), tv((size_t)NV), hl((size_t)(2 * W * KP));
    std::vector<int64_t> row_at(table ? (size_t)K : 0, -1), val_at((size_t)NV, -1);
    std::vector<V> xv_any((size_t)(2 * DD));
    std::vector<T> xt_any((size_t)(DD * W));
    for (int64_t s = 0; s < S && nb > 0; ++s) {
      const T* lr_s = log_lr + s * E;
      const T* cf_s = coef + s * E;
      bool shared = table;
      for (int64_t e = e_lo + 1; shared && e < e_hi; ++e)
        shared = same_bits(lr_s[e], lr_s[e_lo]) && same_bits(cf_s[e], cf_s[e_lo]);
      const T a0 = lr_s[e_lo], c0 = cf_s[e_lo];
      // few distinct distances (a grid: 21 for 4 x 7, 120 for 16 x 16): all their exps at once, then
      // the rows are plain lookups; otherwise (an arbitrary g) only the values the rows need
      const bool eager = shared && NV <= 4 * K;
      if (eager)
        for (int64_t v = 0; v < NV; ++v) tv[(size_t)v] = std::exp(a0 + vals[(size_t)v] * c0);
      LaneStep<T> st{data, x_stride, idx, idx_stride, g, lr_s, cf_s, S, K, D, vidx.data(), vals.data(),
                     KP, H.data(), tv.data(), hl.data(), row_at.data(), val_at.data(), eager, xv_any.data(),
                     xt_any.data()};
      int64_t j = 0;
      for (; j + 2 <= nb; j += 2)  // two blocks at a time: two independent argmin chains interleaved
        lane_step<T, DC, 2>(st, s, shared, a0, c0, wb + j * K * DD, mem.data() + j * W);
      if (j < nb) lane_step<T, DC, 1>(st, s, shared, a0, c0, wb + j * K * DD, mem.data() + j * W);
    }
    for (int64_t j = 0; j < nb; ++j)
      for (int l = 0; l < W && j * W + l + e_lo < e_hi; ++l) {
        T* dst = w + (e_lo + j * W + l) * K * DD;
        for (int64_t i = 0; i < K * DD; ++i) dst[i] = wb[j * K * DD + i][l];
      }
  }
}

template <typename T, int DC>
void dispatch_online(T* w, const T* x, int64_t xs, const int64_t* idx, int64_t is, const T* coef,
                     const T* log_lr, const T* g, int64_t E, int64_t S, int64_t K, int64_t D, int nt) {
  if (E >= kLaneMembers)
    run_online_lanes<T, DC>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt);
  else
    run_online<T, DC>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt);
}

template <typename T>
int entry_online(T* w, const T* x, int64_t xs, const int64_t* idx, int64_t is, const T* coef,
                 const T* log_lr, const T* g, int64_t E, int64_t S, int64_t K, int64_t D, int nt) {
  if (E < 1 || S < 0 || K < 1 || D < 1) return 1;
  if (K > (int64_t)std::numeric_limits<typename Lanes<T, 32>::Idx>::max()) return 1;
  if (has_nan(w, E * K * D)) return 2;
  if (S == 0) return 0;
  switch (D) {
    case 1: dispatch_online<T, 1>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt); break;
    case 2: dispatch_online<T, 2>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt); break;
    case 3: dispatch_online<T, 3>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt); break;
    case 4: dispatch_online<T, 4>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt); break;
    default: dispatch_online<T, 0>(w, x, xs, idx, is, coef, log_lr, g, E, S, K, D, nt); break;
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

// ---- label-map statistics: one pass over an (H, W) map of labels in [-1, K) ----
// The same numbers as torch.bincount over the pixels in row-major order (sums added in that order,
// so the float64 sums are bit-identical), without the key tensors. -1 = no label (skipped).
int label_stats(const int64_t* lab, int64_t H, int64_t W, int64_t K, const double* wts, int64_t M,
                const uint8_t* cont, const int64_t* groups, int64_t G, int do_pairs, int64_t* count,
                double* sums, int64_t* box, int64_t* pairs, int64_t* cpairs, int64_t* gcount) {
  if (H < 0 || W < 0 || K < 1 || M < 0 || (groups != nullptr && G < 1)) return 1;
  const int64_t HW = H * W;
  for (int64_t i = 0; i < HW; ++i)
    if (lab[i] < -1 || lab[i] >= K) return 3;
  if (groups != nullptr)
    for (int64_t i = 0; i < HW; ++i)
      if (lab[i] >= 0 && (groups[i] < 0 || groups[i] >= G)) return 3;
  for (int64_t k = 0; k < K; ++k) {
    box[4 * k] = W;
    box[4 * k + 1] = H;
    box[4 * k + 2] = -1;
    box[4 * k + 3] = -1;
  }
  for (int64_t y = 0; y < H; ++y) {
    const int64_t* row = lab + y * W;
    for (int64_t x = 0; x < W; ++x) {
      const int64_t l = row[x];
      if (l < 0) continue;
      const int64_t i = y * W + x;
      count[l] += 1;
      for (int64_t m = 0; m < M; ++m) sums[m * K + l] += wts[m * HW + i];
      int64_t* b = box + 4 * l;
      if (x < b[0]) b[0] = x;
      if (y < b[1]) b[1] = y;
      if (x > b[2]) b[2] = x;
      if (y > b[3]) b[3] = y;
      if (groups != nullptr) gcount[l * G + groups[i]] += 1;
    }
  }
  if (!do_pairs) return 0;
  // 4-connected pairs: the horizontal ones row by row, then the vertical ones (pair_continuity's order)
  int64_t p = 0;
  for (int64_t y = 0; y < H; ++y) {
    const int64_t* row = lab + y * W;
    for (int64_t x = 0; x + 1 < W; ++x, ++p) {
      const int64_t a = row[x], b = row[x + 1];
      if (a < 0 || b < 0 || a == b) continue;
      pairs[a * K + b] += 1;
      if (cont != nullptr && cont[p]) cpairs[a * K + b] += 1;
    }
  }
  for (int64_t y = 0; y + 1 < H; ++y) {
    const int64_t* row = lab + y * W;
    for (int64_t x = 0; x < W; ++x, ++p) {
      const int64_t a = row[x], b = row[x + W];
      if (a < 0 || b < 0 || a == b) continue;
      pairs[a * K + b] += 1;
      if (cont != nullptr && cont[p]) cpairs[a * K + b] += 1;
    }
  }
  return 0;
}

// The counts the ground fit's RANSAC needs of each plane hypothesis on sampled pixels (see
// somtorch/core/plane_counts.py, torch_plane_counts), as torch computes them in float32:
// pred = c0*x + c1*y + c2 with c the hypothesis rounded to float32 and each product and sum rounded
// (no fused multiply-add: the library is built with -ffp-contract=off); a pixel is an inlier where
// |pred - d| < tol, seen where pred > tol, behind where seen and d < pred - tol (tol as float32).
int plane_counts(const double* coef, int64_t I, const float* xs, const float* ys, const float* ds, int64_t N,
                 float tol, int64_t* inl, int64_t* seen, int64_t* behind) {
  if (I < 0 || N < 0) return 1;
  for (int64_t i = 0; i < I; ++i) {
    const float a = (float)coef[3 * i], b = (float)coef[3 * i + 1], c = (float)coef[3 * i + 2];
    int64_t n_in = 0, n_seen = 0, n_behind = 0;
    for (int64_t j0 = 0; j0 < N; j0 += 1 << 20) {  // int32 counters (vector lanes) per block
      const int64_t j1 = j0 + (1 << 20) < N ? j0 + (1 << 20) : N;
      int32_t b_in = 0, b_seen = 0, b_behind = 0;
      for (int64_t j = j0; j < j1; ++j) {  // branch-free, so that it vectorises
        const float ax = a * xs[j];
        const float by = b * ys[j];
        const float pred = (ax + by) + c;
        const float r = pred - ds[j];
        const int32_t sn = pred > tol;
        b_in += std::fabs(r) < tol;
        b_seen += sn;
        b_behind += sn & (ds[j] < pred - tol);
      }
      n_in += b_in;
      n_seen += b_seen;
      n_behind += b_behind;
    }
    inl[i] = n_in;
    if (seen != nullptr) seen[i] = n_seen;
    if (behind != nullptr) behind[i] = n_behind;
  }
  return 0;
}

// A plane's band over a whole map (see somtorch/core/plane_counts.py, torch_plane_band), as torch
// computes it in float64: plane = (a*x + b*y) + c at pixel (x, y), each product and sum rounded;
// z widened to float64. Where ok: in the band where |plane - z| < tol (mask[p] = 1, counted), seen
// where plane > tol, behind where seen and z < plane - tol. Rows are independent (OpenMP), and the
// counts are integers: the same result at any thread count.
int plane_band(const double* coef, const float* z, const uint8_t* ok, int64_t H, int64_t W, double tol,
               uint8_t* mask, int64_t* counts, int nthreads) {
  if (H < 0 || W < 0) return 1;
  const double a = coef[0], b = coef[1], c = coef[2];
  std::vector<double> ax((size_t)W);
  for (int64_t x = 0; x < W; ++x) ax[(size_t)x] = a * (double)x;
  int64_t n_in = 0, n_seen = 0, n_behind = 0;
#pragma omp parallel for num_threads(nthreads > 0 ? nthreads : 1) reduction(+ : n_in, n_seen, n_behind) \
    schedule(static)
  for (int64_t y = 0; y < H; ++y) {
    const double by = b * (double)y;
    const float* zr = z + y * W;
    const uint8_t* okr = ok + y * W;
    uint8_t* mr = mask + y * W;
    int64_t r_in = 0, r_seen = 0, r_behind = 0;
    for (int64_t x = 0; x < W; ++x) {  // branch-free, so that it vectorises
      const double plane = (ax[(size_t)x] + by) + c;
      const double d = (double)zr[x];
      const uint8_t v = okr[x] != 0;
      const uint8_t in = v & (std::fabs(plane - d) < tol);
      const uint8_t sn = v & (plane > tol);
      mr[x] = in;
      r_in += in;
      r_seen += sn;
      r_behind += sn & (d < plane - tol);
    }
    n_in += r_in;
    n_seen += r_seen;
    n_behind += r_behind;
  }
  counts[0] = n_in;
  counts[1] = n_seen;
  counts[2] = n_behind;
  return 0;
}

}  // namespace

extern "C" {

// Version of this C ABI; native.py refuses a library that reports another one.
int somtorch_bmu_abi(void) { return 7; }

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

int somtorch_online_f32(float* w, const float* x, int64_t x_stride, const int64_t* idx,
                        int64_t idx_stride, const float* coef, const float* log_lr, const float* g,
                        int64_t E, int64_t S, int64_t K, int64_t D, int nthreads) {
  return entry_online<float>(w, x, x_stride, idx, idx_stride, coef, log_lr, g, E, S, K, D, nthreads);
}

int somtorch_online_f64(double* w, const double* x, int64_t x_stride, const int64_t* idx,
                        int64_t idx_stride, const double* coef, const double* log_lr, const double* g,
                        int64_t E, int64_t S, int64_t K, int64_t D, int nthreads) {
  return entry_online<double>(w, x, x_stride, idx, idx_stride, coef, log_lr, g, E, S, K, D, nthreads);
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

// Statistics of one label map (label_stats above): 0 = done, 1 = bad sizes, 3 = a label or group
// out of range (nothing to trust; the caller uses its torch path).
int somtorch_label_stats(const int64_t* lab, int64_t H, int64_t W, int64_t K, const double* wts, int64_t M,
                         const uint8_t* cont, const int64_t* groups, int64_t G, int do_pairs, int64_t* count,
                         double* sums, int64_t* box, int64_t* pairs, int64_t* cpairs, int64_t* gcount) {
  return label_stats(lab, H, W, K, wts, M, cont, groups, G, do_pairs, count, sums, box, pairs, cpairs,
                     gcount);
}

int somtorch_plane_counts(const double* coef, int64_t I, const float* xs, const float* ys, const float* ds,
                          int64_t N, float tol, int64_t* inl, int64_t* seen, int64_t* behind) {
  return plane_counts(coef, I, xs, ys, ds, N, tol, inl, seen, behind);
}

int somtorch_plane_band(const double* coef, const float* z, const uint8_t* ok, int64_t H, int64_t W,
                        double tol, uint8_t* mask, int64_t* counts, int nthreads) {
  return plane_band(coef, z, ok, H, W, tol, mask, counts, nthreads);
}

}  // extern "C"
