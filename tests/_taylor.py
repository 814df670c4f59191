"""Taylor remainders of a Model's energy and gradient, for consistency tests of Pi, grad Pi, hess Pi."""
import numpy as np


def hessian_times(model, x, d, A=None):
    """hess Pi(x) d = K d + sum c g (g . d): the sparse matrix and the rank-one parts kept out of it."""
    A = model.assemble_jacobian(x, A if A is not None else model.create_matrix())
    Ad = d.duplicate()
    A.mult(d, Ad)
    for c, g in model.low_rank(x):
        Ad.axpy(c * g.dot(d), g)
    return Ad


def taylor_rates(model, x, d, hs):
    """Observed orders of Pi(x + h d) - Pi(x) - h R.d and |R(x + h d) - R(x) - h J d| over hs.

    J d is the full Hessian's product (K and the low-rank parts). Both
    remainders are O(h^2) when the gradient and Hessian are exact; d must
    vanish on pinned DOFs.
    """
    b = x.duplicate()
    Ad = hessian_times(model, x, d)
    model.gradient(x, b)
    g = b.array.copy()
    e0 = model.energy(x)
    r1, r2 = [], []
    for h in hs:
        xh = x.copy()
        xh.axpy(h, d)
        bh = x.duplicate()
        model.gradient(xh, bh)
        r1.append(abs(model.energy(xh) - e0 - h * (g @ d.array)))
        r2.append(np.linalg.norm((bh.array - g - h * Ad.array)[~model.fixed]))
    return [np.log2(np.array(r[:-1]) / np.array(r[1:])) for r in (r1, r2)]


def hessian_error(model, x, d, h=1e-5):
    """|(R(x + h d) - R(x - h d)) / 2h - J d| / |J d| on the free DOFs.

    Central differences are O(h^2) accurate: at h = 1e-5 about 1e-10 on the
    test models, far below what a missing part of J (such as a cable's
    rank-one part k g g^T, about 1e-4 of J d there) leaves, which the Taylor
    rates above cannot see behind the elastic O(h^2) remainder.
    """
    free = ~model.fixed[:len(x.array)]
    Jd = hessian_times(model, x, d).array[free]
    grads = []
    for s in (h, -h):
        xs = x.copy()
        xs.axpy(s, d)
        b = x.duplicate()
        model.gradient(xs, b)
        grads.append(b.array[free].copy())
    fd = (grads[0] - grads[1]) / (2 * h)
    return float(np.linalg.norm(fd - Jd) / np.linalg.norm(Jd))


def taylor_orders(energy, gradient, hess_d, z, d, hs):
    """Observed orders of the two Taylor remainders of any smooth f(z) (e.g. a reduced energy):
    f(z + h d) - f(z) - h g.d and |g(z + h d) - g(z) - h H d|, both O(h^2) when g and H d are exact."""
    e0, g0, Hd = energy(z), gradient(z), hess_d(d)
    r1 = [abs(energy(z + h * d) - e0 - h * (g0 @ d)) for h in hs]
    r2 = [np.linalg.norm(gradient(z + h * d) - g0 - h * Hd) for h in hs]
    return [np.log2(np.array(r[:-1]) / np.array(r[1:])) for r in (r1, r2)]
