"""Small vector helpers shared by the models (traced, one trajectory at a time).

Cross products are written out by components: inside vmapped solver loops this is what
XLA fuses best (``jnp.cross`` goes through gathers on some backends).
"""
import jax.numpy as jnp


def cross(a, b):
    return jnp.stack(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a):
    return jnp.sqrt(dot(a, a))


def angle_between(a, b):
    """Angle in [0, pi] via atan2(|a x b|, a.b): accurate near 0 and pi, insensitive to |a|, |b|."""
    return jnp.arctan2(norm(cross(a, b)), dot(a, b))


def hat(v):
    """Skew matrix [v]x with [v]x u = v x u."""
    z = jnp.zeros_like(v[0])
    return jnp.array([[z, -v[2], v[1]], [v[2], z, -v[0]], [-v[1], v[0], z]])
