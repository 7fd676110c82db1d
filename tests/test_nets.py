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


def _traced(layer: nn.Module, n_in: int, input_grad: bool = False) -> tuple[str, list, list]:
    """``layer``'s forward and backward on 256 rows as torch.compile traces them: the Dynamo graph's node
    targets (one string), and the matrix products of the forward and of the backward AOT autograd makes
    (``(first operand's shape, second's)`` of each ``mm`` / ``addmm``)."""
    from functorch.compile import make_boxed_func
    from torch._dynamo.backends.common import aot_autograd

    graphs, products = [], {"forward": [], "backward": []}

    def collect(which):
        def compiler(gm, example_inputs):
            for node in gm.graph.nodes:
                if node.target in (torch.ops.aten.mm.default, torch.ops.aten.addmm.default):
                    operands = node.args[:2] if node.target is torch.ops.aten.mm.default else node.args[1:3]
                    products[which].append(tuple(tuple(arg.meta["val"].shape) for arg in operands))
            return make_boxed_func(gm.forward)

        return compiler

    def backend(gm, example_inputs):
        graphs.append(gm)
        return aot_autograd(fw_compiler=collect("forward"), bw_compiler=collect("backward"))(gm, example_inputs)

    x = torch.randn(256, n_in, requires_grad=input_grad)
    torch.compile(lambda x: layer(x).sum(), backend=backend, fullgraph=True)(x).backward()
    return " ".join(str(node.target) for gm in graphs for node in gm.graph.nodes), products["forward"], products["backward"]


def test_the_layouts_are_taken_where_they_apply(monkeypatch):
    # a first layer, 30 -> 256: the weight gradient's product is (x^T g), 256 wide (its output [30, 256])
    ops, forward, backward = _traced(_pair(30, 256)[0], 30)
    assert "autograd_function_apply" in ops and backward == [((30, 256), (256, 256))], backward
    # a 15-action head: W padded to 16 rows forward (its product 16 wide); the backward's products (dW, dx)
    # are the plain ones
    ops, forward, backward = _traced(_pair(256, 15)[0], 256, input_grad=True)
    assert forward == [((256, 256), (256, 16))], forward
    assert sorted(backward) == [((15, 256), (256, 256)), ((256, 15), (15, 256))], backward
    # a square layer: the plain product and torch's own backward
    ops, forward, backward = _traced(_pair(256, 256)[0], 256, input_grad=True)
    assert "autograd_function_apply" not in ops and forward == [((256, 256), (256, 256))] and len(backward) == 2
    # acting and targets (no gradient): the padded product without an autograd.Function
    padded = []
    monkeypatch.setattr(nets, "_padded_linear", lambda x, w, b, pad: padded.append(pad) or torch.nn.functional.linear(x, w, b))
    head, _ = _pair(256, 15)
    with torch.no_grad():
        head(torch.randn(256, 256))
    assert padded == [1]


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


def test_mlp_relus_run_in_place_after_a_product_that_is_not_a_view():
    torch.manual_seed(0)
    net = nets.mlp(8, (32, 15, 64), 3)  # the 15-unit layer pads its product: its output is a view, its ReLU not in place
    assert [m.inplace for m in net if isinstance(m, nn.ReLU)] == [True, False, True]
    plain = nn.Sequential(*[nn.ReLU() if isinstance(m, nn.ReLU) else m for m in net])  # the same parameters
    x = torch.randn(64, 8)
    out, expected = net(x), plain(x)
    assert torch.equal(out, expected)
    grads = torch.autograd.grad(out.square().sum(), list(net.parameters()))
    for g, e in zip(grads, torch.autograd.grad(expected.square().sum(), list(plain.parameters()))):
        assert torch.equal(g, e)
    with torch.no_grad():
        assert torch.equal(net(x), expected)


def test_in_place_relus_trace_after_the_laid_out_products():
    # traced as a compiled update is: a 30-input first layer (its own backward) and a padded 15-unit hidden layer
    torch.manual_seed(0)
    net = nets.mlp(30, (256, 15, 64), 15)
    plain = nn.Sequential(*[nn.ReLU() if isinstance(m, nn.ReLU) else m for m in net])
    x = torch.randn(256, 30)

    def loss_and_grads(module):
        def step(x):
            y = module(x)
            return (y.detach(), *torch.autograd.grad(y.square().sum(), list(module.parameters())))

        return step

    with torch._dynamo.config.patch(trace_autograd_ops=True):
        got = torch.compile(loss_and_grads(net), backend="aot_eager", fullgraph=True)(x)
    for a, b in zip(got, loss_and_grads(plain)(x)):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
