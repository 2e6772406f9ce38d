/* One consensus round under faults in one pass over the CSR rows of a mixer's in-edge block (plain C, no
 * Python.h). Built by pip as the optional extension distnav._dropround_c and called through ctypes by
 * distnav/_dropround.py; where it is not built the mixer takes its numpy path, which gives the same bits.
 *
 * For each incoming edge e (the CSR entries in their stored order, as scipy's csr_matvec reads them):
 *   delivered = z(e) >= threshold  and  round < dead_from[e]      (dead_from optional: failed links, silent nodes)
 *   z(e)      = SplitMix64(edge_id[e] ^ key), key = SplitMix64(seed * 1000003 + round): distnav.exchange.faults
 *               uniform_hash in integers, u = (z >> 11) / 2^53 >= p  <=>  z >= ceil(p * 2^53) * 2^11 = threshold
 *   lost      = active[e] and not delivered                       (active optional: every edge)
 *   keep      = lost ? 0.0 : 1.0
 *   y_i      += (w * keep) * x_j          the numpy path's masked product term for term (w * 0.0 for a lost entry)
 *   lostw_i  += w - w * keep              w for a lost entry, +0.0 otherwise: np.bincount's sum over the lost ones
 *   then y_i  = y_i + (self_w_i + lostw_i) * xl_i, and lost_acc_i += the row's lost messages.
 * Adding +0.0 leaves every sum unchanged (a sum starting at +0.0 is never -0.0), so the result equals the numpy
 * path bit for bit for finite weights (the loader refuses others). Built with -ffp-contract=off (no fused
 * multiply-add) and no reassociation: every operation rounds as numpy's and scipy's do.
 *
 * Two phases per block of rows, so the hash vectorizes: the keep factors of a block's edges (at most KEEP_BLOCK,
 * a longer row in pieces), then the rows. On x86-64 Linux with GCC the drop-only keep phase is compiled for
 * AVX-512, AVX2 and the baseline and chosen at load time (target_clones); integer arithmetic, the same bits. The
 * round itself is cloned too (issue 27: 3 % of a 10^3-node round in VEX-encoded scalar code; no fused multiply-add
 * with -ffp-contract=off, so the same bits). */
#include <stdint.h>

#if defined(_WIN32)
#define DN_EXPORT __declspec(dllexport)
#else
#define DN_EXPORT __attribute__((visibility("default")))
#endif

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && __GNUC__ >= 11
#define DN_CLONES __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#else
#define DN_CLONES
#endif

#define KEEP_BLOCK 1024

static inline uint64_t dn_splitmix64(uint64_t x) {
    uint64_t z = x + 0x9E3779B97F4A7C15ULL;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

DN_EXPORT int dn_abi_version(void) { return 4; }

/* The key of a round, as FaultPlan._keys. */
DN_EXPORT uint64_t dn_round_key(uint64_t seed, uint64_t round_index) {
    return dn_splitmix64(seed * 1000003ULL + round_index);
}

/* The faults of one round: what the keep phase reads besides the edge ids. */
typedef struct {
    const uint8_t *active;    /* NULL: every edge active */
    const int64_t *dead_from; /* NULL: no failed link or silent sender has begun */
    int64_t round_index;
    uint64_t key, threshold;
} dn_faults;

DN_CLONES static void dn_keep_drops_e32(int64_t n, const int32_t *edges, uint64_t key, uint64_t thr, double *keep) {
    for (int64_t j = 0; j < n; j++) keep[j] = dn_splitmix64((uint64_t)(int64_t)edges[j] ^ key) >= thr ? 1.0 : 0.0;
}

DN_CLONES static void dn_keep_drops_e64(int64_t n, const int64_t *edges, uint64_t key, uint64_t thr, double *keep) {
    for (int64_t j = 0; j < n; j++) keep[j] = dn_splitmix64((uint64_t)edges[j] ^ key) >= thr ? 1.0 : 0.0;
}

/* keep factors of edges [a, b): the fast drop-only loop, or every fault edge by edge */
#define DN_KEEP(NAME, EDGE, FAST)                                                                                    \
    static void NAME(int64_t a, int64_t b, const EDGE *edges, const dn_faults *f, double *keep) {                   \
        if (!f->active && !f->dead_from) {                                                                           \
            FAST(b - a, edges + a, f->key, f->threshold, keep);                                                      \
            return;                                                                                                  \
        }                                                                                                            \
        for (int64_t j = a; j < b; j++) {                                                                            \
            int ok = dn_splitmix64((uint64_t)(int64_t)edges[j] ^ f->key) >= f->threshold;                            \
            if (f->dead_from) ok &= f->round_index < f->dead_from[j];                                                \
            const int lost = (f->active ? f->active[j] != 0 : 1) & !ok;                                              \
            keep[j - a] = lost ? 0.0 : 1.0;                                                                          \
        }                                                                                                            \
    }
DN_KEEP(dn_keep_e32, int32_t, dn_keep_drops_e32)
DN_KEEP(dn_keep_e64, int64_t, dn_keep_drops_e64)

/* A row's running sums. */
typedef struct {
    double sum, lostw, kept;
} dn_row;

/* One fault round; y is (n_rows, k) and written whole, lost_acc (n_rows) is added to. */
#define DN_ROUND(NAME, IDX, EDGE, KEEP)                                                                              \
    static inline void NAME##_edges(int64_t a, int64_t b, const double *keep, const IDX *indices,                   \
                                    const double *data, const double *cols, int64_t k, double *yi, dn_row *r) {     \
        double sum = r->sum, lostw = r->lostw, kept = r->kept; /* locals: no store-load per entry */                \
        if (k == 1) {                                                                                                \
            for (int64_t jj = a; jj < b; jj++) {                                                                     \
                const double w = data[jj], f = keep[jj - a], wd = w * f;                                             \
                sum += wd * cols[indices[jj]];                                                                       \
                lostw += w - wd;                                                                                     \
                kept += f;                                                                                           \
            }                                                                                                        \
        } else {                                                                                                     \
            for (int64_t jj = a; jj < b; jj++) {                                                                     \
                const double w = data[jj], f = keep[jj - a], wd = w * f;                                             \
                const double *xj = cols + (int64_t)indices[jj] * k;                                                  \
                for (int64_t c = 0; c < k; c++) yi[c] += wd * xj[c];                                                 \
                lostw += w - wd;                                                                                     \
                kept += f;                                                                                           \
            }                                                                                                        \
        }                                                                                                            \
        r->sum = sum, r->lostw = lostw, r->kept = kept;                                                              \
    }                                                                                                                \
    DN_EXPORT DN_CLONES void NAME(int64_t n_rows, int64_t k, const IDX *indptr, const IDX *indices,                  \
                                  const double *data, const EDGE *edges, const uint8_t *active,                      \
                                  const int64_t *dead_from, int64_t round_index, uint64_t seed, uint64_t threshold,  \
                                  const double *cols, const double *self_w, const double *xl, double *y,             \
                                  int64_t *lost_acc) {                                                               \
        const dn_faults f = {active, dead_from, round_index, dn_round_key(seed, (uint64_t)round_index), threshold};                                        \
        double keep[KEEP_BLOCK];                                                                                     \
        int64_t i = 0;                                                                                               \
        while (i < n_rows) {                                                                                         \
            const int64_t a0 = (int64_t)indptr[i];                                                                   \
            int64_t end = i + 1;                                                                                     \
            while (end < n_rows && (int64_t)indptr[end + 1] - a0 <= KEEP_BLOCK) end++;                               \
            const int64_t b0 = (int64_t)indptr[end];                                                                 \
            if (b0 - a0 <= KEEP_BLOCK) KEEP(a0, b0, edges, &f, keep);                                                \
            if (k == 1 && b0 - a0 <= KEEP_BLOCK) { /* the common case in its own tight loop */                       \
                const double *kp = keep - a0;                                                                        \
                for (; i < end; i++) {                                                                               \
                    const int64_t a = (int64_t)indptr[i], b = (int64_t)indptr[i + 1];                                \
                    double sum = 0.0, lostw = 0.0, kept = 0.0;                                                       \
                    for (int64_t jj = a; jj < b; jj++) {                                                             \
                        const double w = data[jj], fk = kp[jj], wd = w * fk;                                         \
                        sum += wd * cols[indices[jj]];                                                               \
                        lostw += w - wd;                                                                             \
                        kept += fk;                                                                                  \
                    }                                                                                                \
                    y[i] = sum + (self_w[i] + lostw) * xl[i];                                                        \
                    lost_acc[i] += (b - a) - (int64_t)kept;                                                          \
                }                                                                                                    \
                continue;                                                                                            \
            }                                                                                                        \
            for (; i < end; i++) {                                                                                   \
                const int64_t a = (int64_t)indptr[i], b = (int64_t)indptr[i + 1];                                    \
                double *yi = y + i * k;                                                                              \
                dn_row r = {0.0, 0.0, 0.0};                                                                          \
                for (int64_t c = 0; c < k; c++) yi[c] = 0.0;                                                         \
                if (b0 - a0 <= KEEP_BLOCK) {                                                                         \
                    NAME##_edges(a, b, keep + (a - a0), indices, data, cols, k, yi, &r);                             \
                } else { /* one row longer than a block: its keep factors a block at a time */                      \
                    for (int64_t p = a; p < b; p += KEEP_BLOCK) {                                                    \
                        const int64_t q = b - p < KEEP_BLOCK ? b : p + KEEP_BLOCK;                                   \
                        KEEP(p, q, edges, &f, keep);                                                                 \
                        NAME##_edges(p, q, keep, indices, data, cols, k, yi, &r);                                    \
                    }                                                                                                \
                }                                                                                                    \
                const double s = self_w[i] + r.lostw;                                                                \
                if (k == 1) {                                                                                        \
                    y[i] = r.sum + s * xl[i];                                                                        \
                } else {                                                                                             \
                    for (int64_t c = 0; c < k; c++) yi[c] = yi[c] + s * xl[i * k + c];                               \
                }                                                                                                    \
                lost_acc[i] += (b - a) - (int64_t)r.kept;                                                            \
            }                                                                                                        \
        }                                                                                                            \
    }

DN_ROUND(dn_fault_round_i32_e32, int32_t, int32_t, dn_keep_e32)
DN_ROUND(dn_fault_round_i32_e64, int32_t, int64_t, dn_keep_e64)
DN_ROUND(dn_fault_round_i64_e32, int64_t, int32_t, dn_keep_e32)
DN_ROUND(dn_fault_round_i64_e64, int64_t, int64_t, dn_keep_e64)

/* The lost mask of edges [0, n) in one round (the keep phase alone: for tests against FaultPlan.delivered). */
#define DN_LOST_MASK(NAME, EDGE, KEEP)                                                                               \
    DN_EXPORT void NAME(int64_t n, const EDGE *edges, const uint8_t *active, const int64_t *dead_from,              \
                        int64_t round_index, uint64_t seed, uint64_t threshold, uint8_t *lost) {                     \
        const dn_faults f = {active, dead_from, round_index, dn_round_key(seed, (uint64_t)round_index), threshold};                                        \
        double keep[KEEP_BLOCK];                                                                                     \
        for (int64_t a = 0; a < n; a += KEEP_BLOCK) {                                                                \
            const int64_t b = n - a < KEEP_BLOCK ? n : a + KEEP_BLOCK;                                               \
            KEEP(a, b, edges, &f, keep);                                                                             \
            for (int64_t j = a; j < b; j++) lost[j] = keep[j - a] == 0.0;                                            \
        }                                                                                                            \
    }

/* One fault round with its arguments in one struct, so the caller sets what changes (round, value and output
 * addresses) in a prepared struct and passes one pointer: a call from ctypes then converts one argument, not 16
 * (about 1 us of the few us a 10^3-node round takes). kind: 0..3 for i32_e32, i32_e64, i64_e32, i64_e64. */
typedef struct {
    int64_t kind, n_rows;
    const void *indptr, *indices, *data, *edges;
    const uint8_t *active;
    uint64_t seed, threshold;
    const double *self_w;
    const int64_t *dead_from;
    int64_t *lost_acc;
    /* what changes from round to round, together at the end: the caller writes them in one step */
    int64_t k, round_index;
    const double *cols, *xl;
    double *y;
} dn_round_args;

DN_EXPORT void dn_fault_round(const dn_round_args *a) {
#define DN_CALL(NAME, IDX, EDGE)                                                                                     \
    NAME(a->n_rows, a->k, (const IDX *)a->indptr, (const IDX *)a->indices, (const double *)a->data,                   \
         (const EDGE *)a->edges, a->active, a->dead_from, a->round_index, a->seed, a->threshold, a->cols, a->self_w,  \
         a->xl, a->y, a->lost_acc)
    switch (a->kind) {
    case 0: DN_CALL(dn_fault_round_i32_e32, int32_t, int32_t); break;
    case 1: DN_CALL(dn_fault_round_i32_e64, int32_t, int64_t); break;
    case 2: DN_CALL(dn_fault_round_i64_e32, int64_t, int32_t); break;
    default: DN_CALL(dn_fault_round_i64_e64, int64_t, int64_t); break;
    }
#undef DN_CALL
}

DN_LOST_MASK(dn_lost_mask_e32, int32_t, dn_keep_e32)
DN_LOST_MASK(dn_lost_mask_e64, int64_t, dn_keep_e64)
