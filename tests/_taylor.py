"""Taylor remainders of a Scene's energy and gradient, for consistency tests of Pi, grad Pi, hess Pi."""
import numpy as np


def taylor_rates(sc, x, d, hs):
    """Observed orders of Pi(x + h d) - Pi(x) - h R.d and |R(x + h d) - R(x) - h J d| over hs.

    Both are O(h^2) when the gradient and Jacobian are exact; d must vanish on pinned DOFs.
    """
    b, A = x.duplicate(), sc.create_matrix()
    sc.gradient(x, b)
    sc.jacobian(x, A)
    g = b.array.copy()
    Ad = d.duplicate()
    A.mult(d, Ad)
    e0 = sc.energy(x)
    r1, r2 = [], []
    for h in hs:
        xh = x.copy()
        xh.axpy(h, d)
        bh = x.duplicate()
        sc.gradient(xh, bh)
        r1.append(abs(sc.energy(xh) - e0 - h * (g @ d.array)))
        r2.append(np.linalg.norm((bh.array - g - h * Ad.array)[~sc.fixed]))
    return [np.log2(np.array(r[:-1]) / np.array(r[1:])) for r in (r1, r2)]
