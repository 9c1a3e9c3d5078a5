"""pyMOR's demo wave with a parameter (the ``wave`` fixture of tests/conftest.py, and the MOR tests)."""

import pytest
from pymor.operators.block import BlockDiagonalOperator
from pymor.operators.constructions import LincombOperator
from pymor.parameters.functionals import ExpressionParameterFunctional


def parametric_wave(T=1.0, H_expr="c[0]**2/0.01", params=None):
    """pyMOR's demo wave with the stiffness block scaled by a parameter functional (c = 0.1 is the demo)."""
    pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")
    fom = pymordemos.discretize_fom(T=T)
    blocks = fom.H_op.blocks
    H_op = BlockDiagonalOperator(
        [LincombOperator([blocks[0, 0]], [ExpressionParameterFunctional(H_expr, params or {"c": 1})]), blocks[1, 1]]
    )
    return fom.with_(H_op=H_op, name="wave_c")
