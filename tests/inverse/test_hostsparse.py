"""HostCSR: scipy CSR applied from JAX — values, JVP, transpose and gradient."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from lftomo.inverse.hostsparse import host_csr

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def mat():
    A = sp.random(40, 25, density=0.2, format="csr", random_state=3)
    return A, host_csr(A)


def test_matvec_jvp_transpose_grad_match_scipy(mat):
    A, op = mat
    rng = np.random.default_rng(0)
    x = rng.normal(size=25)
    v = rng.normal(size=25)
    u = rng.normal(size=40)

    def f(z):
        return op @ jnp.exp(z)

    np.testing.assert_allclose(jax.jit(f)(x), A @ np.exp(x), rtol=1e-13)
    _, t = jax.jvp(f, (jnp.asarray(x),), (jnp.asarray(v),))
    np.testing.assert_allclose(t, A @ (np.exp(x) * v), rtol=1e-12)
    _, lin = jax.linearize(f, jnp.asarray(x))
    (ct,) = jax.linear_transpose(lin, jnp.asarray(x))(jnp.asarray(u))
    np.testing.assert_allclose(ct, np.exp(x) * (A.T @ u), rtol=1e-12)
    g = jax.jit(jax.grad(lambda z: jnp.sum(jnp.sin(f(z)))))(jnp.asarray(x))
    np.testing.assert_allclose(g, np.exp(x) * (A.T @ np.cos(A @ np.exp(x))), rtol=1e-12)


def test_bad_input(mat):
    _, op = mat
    with pytest.raises(ValueError, match="does not match"):
        op @ jnp.ones(24)
    with pytest.raises(ValueError, match="scipy sparse"):
        host_csr(np.ones((3, 3)))
