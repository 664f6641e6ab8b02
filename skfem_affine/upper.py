"""A symmetric matrix whole from its upper triangle, in one compiled pass."""
import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)


@njit(cache=True)
def _whole(indptr, indices, data):
    """CSR arrays of U + U^T - diag(U) from the upper triangle U (rows sorted); entries equal to zero
    are left out, as scipy's sum leaves them."""
    n = indptr.size - 1
    lower = np.zeros(n + 1, dtype=np.int64)  # entries of each row below the diagonal
    count = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            if data[p] != 0.0:
                count[i + 1] += 1
                if indices[p] > i:
                    lower[indices[p]] += 1
                    count[indices[p] + 1] += 1
    for i in range(n):
        count[i + 1] += count[i]
    out_ind = np.empty(count[n], dtype=np.int32)
    out_val = np.empty(count[n])
    fill = count[:n].copy()  # the entries below the diagonal first, rows j < i in increasing order
    for i in range(n):
        q = count[i] + lower[i]
        for p in range(indptr[i], indptr[i + 1]):
            v = data[p]
            if v != 0.0:
                j = indices[p]
                out_ind[q], out_val[q] = j, v
                q += 1
                if j > i:
                    out_ind[fill[j]], out_val[fill[j]] = i, v
                    fill[j] += 1
    return count.astype(np.int32), out_ind, out_val


def whole_from_upper(U):
    """The symmetric CSR matrix whose upper triangle (diagonal included) is U (CSR, rows sorted): the
    entries and order of ``U + triu(U, 1).T`` in scipy, without its transposes and sorts."""
    U = sp.csr_matrix(U)
    if not U.has_sorted_indices:
        U = U.sorted_indices()
    indptr, indices, data = _whole(U.indptr, U.indices, np.asarray(U.data, dtype=float))
    return sp.csr_matrix((data, indices, indptr), shape=U.shape)
