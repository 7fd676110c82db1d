"""nets.Linear: nn.Linear's numbers, in the layouts a CPU runs fastest."""

import pytest
import torch
from torch import nn

from taskrl import nets

# (rows, in, out): a 30-input first layer (dW laid out wide), a 15-action head (W padded to 16 rows),
# a 17-input critic layer, and a square layer that keeps the plain path.
SHAPES = [(256, 30, 256), (256, 256, 15), (256, 17, 256), (256, 256, 256), (256, 256, 30)]


def _pair(n_in: int, n_out: int) -> tuple[nets.Linear, nn.Linear]:
    torch.manual_seed(0)
    laid_out = nets.Linear(n_in, n_out)
    plain = nn.Linear(n_in, n_out)
    plain.load_state_dict(laid_out.state_dict())
    return laid_out, plain


def _outputs_and_grads(layer: nn.Module, x: torch.Tensor, g: torch.Tensor, compiled: bool):
    x = x.clone().requires_grad_()

    def forward_backward(x):
        y = layer(x)
        return (y.detach(), *torch.autograd.grad((y * g).sum(), [x, layer.weight, layer.bias]))

    if not compiled:
        return forward_backward(x)
    with torch._dynamo.config.patch(trace_autograd_ops=True):  # as agents.compiled traces an update
        return torch.compile(forward_backward, backend="aot_eager", fullgraph=True)(x)


@pytest.mark.parametrize("rows,n_in,n_out", SHAPES)
@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "traced"])
def test_laid_out_products_give_nn_linears_outputs_and_gradients(rows, n_in, n_out, compiled):
    laid_out, plain = _pair(n_in, n_out)
    x, g = torch.randn(rows, n_in), torch.randn(rows, n_out)
    got = _outputs_and_grads(laid_out, x, g, compiled)
    want = _outputs_and_grads(plain, x, g, compiled=False)
    for a, b, name in zip(got, want, ("y", "dx", "dW", "db")):
        assert a.shape == b.shape, name
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6, msg=name)


def _traced(layer: nn.Module, n_in: int, grad: bool = True, input_grad: bool = False) -> tuple[str, list]:
    """The Dynamo graph of ``layer``'s forward (its node targets, one string) and the products of its
    backward as AOT autograd traces them (``(first operand's shape, second's)`` of each ``mm``)."""
    from functorch.compile import make_boxed_func
    from torch._dynamo.backends.common import aot_autograd

    graphs, products = [], []

    def backward(gm, example_inputs):
        products.extend(
            tuple(tuple(arg.meta["val"].shape) for arg in node.args[:2])
            for node in gm.graph.nodes
            if node.target is torch.ops.aten.mm.default
        )
        return make_boxed_func(gm.forward)

    def backend(gm, example_inputs):
        graphs.append(gm)
        return aot_autograd(fw_compiler=lambda gm, _: make_boxed_func(gm.forward), bw_compiler=backward)(gm, example_inputs)

    with torch.set_grad_enabled(grad):
        x = torch.randn(256, n_in, requires_grad=input_grad)
        out = torch.compile(lambda x: layer(x).sum(), backend=backend, fullgraph=True)(x)
    if grad:
        out.backward()
    return " ".join(str(node.target) for gm in graphs for node in gm.graph.nodes), products


def test_the_layouts_are_taken_where_they_apply():
    # a first layer, 30 -> 256: the weight gradient's product is (x^T g), 256 wide (its output [30, 256])
    ops, products = _traced(_pair(30, 256)[0], 30)
    assert "contiguous" in ops and products == [((30, 256), (256, 256))], products
    # a 15-action head: W padded to 16 rows; its backward's products (dW, dx) are the padded ones
    ops, products = _traced(_pair(256, 15)[0], 256, input_grad=True)
    assert "pad" in ops and sorted(products) == [((16, 256), (256, 256)), ((256, 16), (16, 256))], products
    # a square layer: the plain product and torch's own backward
    ops, products = _traced(_pair(256, 256)[0], 256, input_grad=True)
    assert "pad" not in ops and "contiguous" not in ops and len(products) == 2
    # acting and targets (no gradient) pad the head too
    assert "pad" in _traced(_pair(256, 15)[0], 256, grad=False)[0]
    # plain tensor operations only: an autograd.Function would keep compiled updates out of torch's compile cache
    for n_in, n_out in ((30, 256), (256, 15)):
        assert "autograd_function_apply" not in _traced(_pair(n_in, n_out)[0], n_in)[0]


def test_batched_inputs_keep_their_leading_shape():
    layer, plain = _pair(256, 15)
    x = torch.randn(4, 64, 256)
    with torch.no_grad():
        torch.testing.assert_close(layer(x), plain(x), rtol=1e-6, atol=1e-6)


def test_the_observation_concat_is_the_same_compiled_and_eager():
    """Compiled, the parts are cast before the concat (one generated kernel); eager, after it: the same values in the same order."""
    concat = nets.ObsConcat(("observation", "desired_goal"))
    g = torch.Generator().manual_seed(0)
    obs = {
        "observation": torch.randint(0, 2, (8, 5), dtype=torch.int8, generator=g),
        "desired_goal": torch.randint(0, 2, (8, 3), dtype=torch.int8, generator=g),
    }
    eager = concat(obs)
    compiled = torch.compile(concat, fullgraph=True, dynamic=False)(obs)
    expected = torch.cat([obs["observation"].float(), obs["desired_goal"].float()], dim=1)
    assert eager.dtype == compiled.dtype == torch.float32
    assert torch.equal(eager, expected) and torch.equal(compiled, expected)
