import pytest
import torch

from neuraldem.models.modules.multi_branch_block import MultiBranchTransformerBlock
from tests.models.nets import activate_modulations

MAIN, OFF = ["particles", "fluid"], ["mixing"]


def make_block() -> MultiBranchTransformerBlock:
    torch.manual_seed(0)
    return activate_modulations(MultiBranchTransformerBlock(16, 2, 8, MAIN, OFF))


def make_tokens() -> dict[str, torch.Tensor]:
    return {"particles": torch.randn(2, 5, 16), "fluid": torch.randn(2, 6, 16),
            "mixing": torch.randn(2, 6, 16)}


def test_shapes():
    out = make_block()(make_tokens(), torch.randn(2, 8))
    assert {k: v.shape for k, v in out.items()} == {k: v.shape for k, v in make_tokens().items()}


def test_fresh_block_is_identity():
    block = MultiBranchTransformerBlock(16, 2, 8, MAIN, OFF)
    tokens = make_tokens()
    out = block(tokens, torch.randn(2, 8))
    assert all(torch.equal(out[k], tokens[k]) for k in tokens)


def test_no_weight_sharing_between_branches():
    block = make_block()
    branches = [*block.main.items(), *block.off.items()]
    ids = {name: {id(p) for p in branch.parameters()} for name, branch in branches}
    assert not (ids["particles"] & ids["fluid"]) and not (ids["fluid"] & ids["mixing"])


def test_main_branches_attend_jointly():
    block, tokens, cond = make_block(), make_tokens(), torch.randn(2, 8)
    changed = dict(tokens, fluid=torch.randn(2, 6, 16))
    assert not torch.allclose(block(changed, cond)["particles"], block(tokens, cond)["particles"])


def test_off_branch_reads_main_tokens():
    block, tokens, cond = make_block(), make_tokens(), torch.randn(2, 8)
    changed = dict(tokens, particles=torch.randn(2, 5, 16))
    assert not torch.allclose(block(changed, cond)["mixing"], block(tokens, cond)["mixing"])


def test_off_branch_cannot_change_main_branches():
    block, tokens, cond = make_block(), make_tokens(), torch.randn(2, 8)
    out = block(tokens, cond)
    changed = block(dict(tokens, mixing=torch.randn(2, 9, 16)), cond)  # other values and token count
    for name in MAIN:
        assert torch.equal(changed[name], out[name])


def test_off_branch_loss_sends_no_gradient_into_main_branches():
    block, tokens = make_block(), make_tokens()
    for t in tokens.values():
        t.requires_grad_(True)
    cond = torch.randn(2, 8, requires_grad=True)
    block(tokens, cond)["mixing"].square().sum().backward()
    for name in MAIN:
        assert tokens[name].grad is None
        for param in block.main[name].parameters():
            assert param.grad is None or torch.all(param.grad == 0)
    assert cond.grad is None  # the conditioning vector is shared with the main branches
    assert tokens["mixing"].grad.abs().sum() > 0
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in block.off["mixing"].q.parameters())


def test_branch_names_are_validated():
    with pytest.raises(ValueError, match="must be non-empty and distinct"):
        MultiBranchTransformerBlock(16, 2, 8, ["a", "b"], ["b"])
    with pytest.raises(ValueError, match="must be non-empty and distinct"):
        MultiBranchTransformerBlock(16, 2, 8, [], ["b"])
    with pytest.raises(ValueError, match="missing"):
        make_block()({"particles": torch.randn(2, 5, 16)}, torch.randn(2, 8))
