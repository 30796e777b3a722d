"""Exact reductions that the compiler vectorises: extremes over integer keys, and the
four-lane sums of a row in vector registers.

A loop `m = max(m, a[i])` over doubles compiles to one scalar compare-and-select after another:
without fast-math the compiler may not reorder a floating-point maximum (NaN), so it is never
vectorised, and Numba offers no per-operation flag that would allow it (measured: with
`fastmath=True` as well it stays scalar, 0.33 ns an element). The same loop over int64 is an
integer reduction, which the compiler vectorises (0.06 ns an element, AVX-512 here; scratch
timing of a 101-element row).

order_key maps a double to an int64 that orders as the double does: x < y ⇔ key(x) < key(y) for
any two doubles that are not NaN, with −0.0 below +0.0 (IEEE 754's bits are sign and magnitude:
a non-negative double's bits already order as integers; a negative one's magnitude bits are
flipped so that a larger magnitude gives a smaller key). from_key is its inverse. So the
largest and smallest of a row are exact — the same double that the scalar loop returns — except
that where +0.0 and −0.0 tie for the extreme, the key picks by sign where the scalar loop kept
whichever came first. A NaN gets a key beyond ±inf's and comes back as a NaN where it is the
extreme; the step kernels catch a non-finite state from their sums, not from these extremes.
"""

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

SCAN_BLOCK = 64
"""Entries a sparse scan counts at once (a count vectorises; the block is then searched only where
the count is not zero): the passes over every node or segment of a step that look for the few
that matter (contact candidates, a node inside the body, damage that fell)."""

MAGNITUDE = 0x7FFFFFFFFFFFFFFF
"""The bits of a double without its sign."""


@intrinsic
def _bits(typingctx, x):
    """The bits of a double as an int64 (no conversion: a bit cast)."""
    if not isinstance(x, types.Float) or x.bitwidth != 64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int64))

    return types.int64(types.float64), codegen


@intrinsic
def _double(typingctx, k):
    """The double whose bits are the int64 k (a bit cast)."""
    if not isinstance(k, types.Integer) or k.bitwidth != 64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@njit(cache=True, inline="always")
def order_key(x):
    """An int64 that orders as the double x does (module docstring); x's bits where x ≥ +0.0."""
    b = _bits(x)
    return b ^ ((b >> 63) & MAGNITUDE)


@njit(cache=True, inline="always")
def from_key(k):
    """The double whose order_key is k."""
    return _double(k ^ ((k >> 63) & MAGNITUDE))


@intrinsic
def lane_sums(typingctx, buf, r, count):
    """The four partial sums (s₀, s₁, s₂, s₃) of buf[r, :4⌊count/4⌋], s_k = Σ buf[r, 4q + k]
    in increasing q (buf a C-contiguous 2-D float64 array, r a row, count ≥ 0): the sums of
    four scalar accumulators, added in one 4-wide vector register. The compiler keeps four
    scalar chains as they are (measured: no vector add, ~1 cycle an element) and may not
    reorder them into wider vectors without fast-math, which would change the rounding; a
    <4 x double> fadd is the four IEEE additions themselves, so the sums are the same to the
    bit as the scalar loop's, at a quarter of the instructions."""
    if not (isinstance(buf, types.Array) and buf.ndim == 2 and buf.layout == "C"
            and buf.dtype == types.float64 and isinstance(r, types.Integer)
            and isinstance(count, types.Integer)):
        return None
    result = types.UniTuple(types.float64, 4)

    def codegen(context, builder, signature, args):
        arrty, rty, cty = signature.args
        ary = context.make_array(arrty)(context, builder, value=args[0])
        i64 = ir.IntType(64)
        double = ir.DoubleType()
        vec = ir.VectorType(double, 4)
        row = context.cast(builder, args[1], rty, types.int64)
        n = context.cast(builder, args[2], cty, types.int64)
        stride = cgutils.unpack_tuple(builder, ary.shape, 2)[1]
        start = builder.gep(ary.data, [builder.mul(row, stride)])
        acc = cgutils.alloca_once_value(builder, ir.Constant(vec, [0.0] * 4))
        blocks = builder.sdiv(n, ir.Constant(i64, 4))
        with cgutils.for_range(builder, blocks) as loop:
            p = builder.gep(start, [builder.mul(loop.index, ir.Constant(i64, 4))])
            v = builder.load(builder.bitcast(p, vec.as_pointer()), align=8)
            builder.store(builder.fadd(builder.load(acc), v), acc)
        total = builder.load(acc)
        lanes = [builder.extract_element(total, ir.Constant(ir.IntType(32), k))
                 for k in range(4)]
        return context.make_tuple(builder, result, lanes)

    return result(buf, r, count), codegen
