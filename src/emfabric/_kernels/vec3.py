"""3-vectors as tuples, 3 × 3 matrices as arrays, and small dense solves — without LAPACK or BLAS.

Numba's `np.linalg` and matrix `@` call LAPACK/BLAS through SciPy, which a plain install does not
have, and they cost seconds of compile time for systems of three unknowns. These few functions
do the same arithmetic in plain loops: no allocation for vectors, and the same result on every
machine (no BLAS build or thread count in the rounding). The one-line ones are inlined into their
callers (Numba IR): a separately compiled small function costs a fixed ~0.2 s on the first run;
those with loops are compiled once and called.
"""

import math

from numba import njit


@njit(cache=True, inline="always")
def vec(a):
    """A length-3 array (or row of one) as a tuple."""
    return (a[0], a[1], a[2])


@njit(cache=True, inline="always")
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True, inline="always")
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def distance_sq(x, u, c):
    """|x[:, u] − c|² for a (3, N) array x, a column u and a point c (a tuple): the
    components' squares added left to right, as the scans of every node compare them."""
    dx = x[0, u] - c[0]
    dy = x[1, u] - c[1]
    dz = x[2, u] - c[2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def mat_vec(m, v):
    """m · v for a 3 × 3 array m."""
    return (m[0, 0] * v[0] + m[0, 1] * v[1] + m[0, 2] * v[2],
            m[1, 0] * v[0] + m[1, 1] * v[1] + m[1, 2] * v[2],
            m[2, 0] * v[0] + m[2, 1] * v[1] + m[2, 2] * v[2])


@njit(cache=True, inline="always")
def mat_t_vec(m, v):
    """mᵀ · v for a 3 × 3 array m."""
    return (m[0, 0] * v[0] + m[1, 0] * v[1] + m[2, 0] * v[2],
            m[0, 1] * v[0] + m[1, 1] * v[1] + m[2, 1] * v[2],
            m[0, 2] * v[0] + m[1, 2] * v[1] + m[2, 2] * v[2])


@njit(cache=True, inline="always")
def to_body_frame(rot, d):
    """Rᵀ·d: a world-frame vector d in the body frame of rotation R."""
    return mat_t_vec(rot, d)


@njit(cache=True)
def mat_mul(a, b, out):
    """out = a · b for 3 × 3 arrays (out must not alias a or b)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def solve_in_place(a, b, n):
    """Solve a[:n, :n] · x = b[:n] by Gaussian elimination with partial pivoting; a and b are
    overwritten, x is left in b. A singular pivot gives inf/nan, which the callers' finiteness
    checks report."""
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(a[r, col]) > abs(a[piv, col]):
                piv = r
        if piv != col:
            for c in range(n):
                a[col, c], a[piv, c] = a[piv, c], a[col, c]
            b[col], b[piv] = b[piv], b[col]
        inv = 1.0 / a[col, col]
        for r in range(col + 1, n):
            f = a[r, col] * inv
            if f != 0.0:
                for c in range(col + 1, n):
                    a[r, c] -= f * a[col, c]
                b[r] -= f * b[col]
    for r in range(n - 1, -1, -1):
        s = b[r]
        for c in range(r + 1, n):
            s -= a[r, c] * b[c]
        b[r] = s / a[r, r]


@njit(cache=True, _nrt=True)
def solve3(m, v, scratch):
    """m⁻¹ · v for a 3 × 3 array m (partial pivoting), as a tuple; scratch (4, 3) is
    overwritten (rows 0–2 the eliminated matrix, row 3 the solution)."""
    a = scratch[0:3]
    b = scratch[3]
    for i in range(3):
        for j in range(3):
            a[i, j] = m[i, j]
    b[0], b[1], b[2] = v[0], v[1], v[2]
    solve_in_place(a, b, 3)
    return (b[0], b[1], b[2])


@njit(cache=True)
def rotation_increment(theta, out):
    """out = the rotation by the vector angle theta (Rodrigues; equals Aᵀ·R(Δθ)·A of B13–B14)."""
    angle = norm(theta)
    for i in range(3):
        for j in range(3):
            out[i, j] = 1.0 if i == j else 0.0
    if angle == 0.0:
        return
    k = (theta[0] / angle, theta[1] / angle, theta[2] / angle)
    s = math.sin(angle)
    c1 = 1.0 - math.cos(angle)
    # I + sin·K + (1 − cos)·K², K the cross-product matrix of k, K² = k kᵀ − I
    for i in range(3):
        for j in range(3):
            out[i, j] += c1 * (k[i] * k[j] - (1.0 if i == j else 0.0))
    out[0, 1] -= s * k[2]
    out[0, 2] += s * k[1]
    out[1, 0] += s * k[2]
    out[1, 2] -= s * k[0]
    out[2, 0] -= s * k[1]
    out[2, 1] += s * k[0]


@njit(cache=True, inline="always")
def world_inertia_times(rot, inertia_body, w):
    """Ī·ω with the inertia rotated into the inertial frame, Ī = R I Rᵀ (B15), as R(I(Rᵀω))."""
    return mat_vec(rot, mat_vec(inertia_body, mat_t_vec(rot, w)))


@njit(cache=True, inline="always")
def world_inertia_solve(rot, inertia_body, h, scratch):
    """Ī⁻¹·h for Ī = R I Rᵀ, as R(I⁻¹(Rᵀh)) (R orthogonal: the same system, solved in the body
    frame); scratch (4, 3) as solve3's."""
    return mat_vec(rot, solve3(inertia_body, mat_t_vec(rot, h), scratch))


@njit(cache=True, inline="always")
def tilt_angle(rot, nose_body):
    """Angle between the nose marker now (R·n) and at t = 0 (n), eq. 5.2 in atan2 form."""
    now = mat_vec(rot, nose_body)
    return math.atan2(norm(cross(now, nose_body)), dot(now, nose_body))


@njit(cache=True, inline="always")
def yaw_angle(rot, nose_body, v):
    """Angle between the body axis now (R·n, n the nose marker) and the velocity v [rad], in
    atan2 form; 0 for a body at rest."""
    axis = mat_vec(rot, nose_body)
    return math.atan2(norm(cross(axis, v)), dot(axis, v))


@njit(cache=True, _nrt=True)
def copy_into(dst, src):
    """dst[...] = src for 2-D arrays of one shape, as a plain loop: Numba's array assignment
    compiles a broadcast check whose error message alone costs seconds of first-run compile."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=True, inline="always")
def to_shape_frame(rot, frame, d):
    """A world-frame vector d in the shape's own frame: frame · (Rᵀ d) (rot: body → inertial,
    frame: rows e1, e2, e3 of the shape's axes in the body frame)."""
    return mat_vec(frame, mat_t_vec(rot, d))


@njit(cache=True, inline="always")
def from_shape_frame(rot, frame, q):
    """Inverse of to_shape_frame: R · (frameᵀ q)."""
    return mat_vec(rot, mat_t_vec(frame, q))
