"""scripts/check_product_text.sh: no internal work-round names in the product's files or paths. This checkout passes;
a repository with a planted round word and a round-numbered path fails and names both, while ordinary words
(round-off, issue a warning, stop at a step) and the files the check leaves out pass."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "check_product_text.sh"


def _check(repo: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), str(repo)], capture_output=True, text=True, timeout=120, check=False)


def _repo(tmp_path: Path, files: dict[str, str]) -> Path:
    repo = tmp_path / "repo"
    for rel, text in files.items():
        path = repo / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    subprocess.run(["git", "-C", str(repo), "add", "-A"], check=True)
    return repo


LEGIT = {
    "docs/ok.md": "Solid volume to round-off; the reader may issue a warning; a rollout may stop at step 137.\n",
    "src/pkg/mod.py": "# values round to 3 digits; the rollout stops after 3000 steps\nx = stop_gradient(1)\n",
    "CHANGELOG.md": "stop 43 is allowed here\n",
    "other/notes.md": "issue 20, outside the checked folders\n",
}


def test_this_checkout_names_no_work_round():
    proc = _check(ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 line(s), 0 path(s)" in proc.stdout


def test_ordinary_words_and_left_out_files_pass(tmp_path: Path):
    proc = _check(_repo(tmp_path, LEGIT))
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_a_planted_round_word_and_path_fail_by_name(tmp_path: Path):
    repo = _repo(tmp_path, {**LEGIT, "docs/page.md": "Intro.\nAs measured in stop 43, the bed holds.\n",
                            "results/x_stop41.md": "a table\n", "tests/test_x.py": "# issue-20 options\n"})
    proc = _check(repo)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "docs/page.md:2:" in proc.stdout and "tests/test_x.py:1:" in proc.stdout
    assert "results/x_stop41.md" in proc.stdout
    assert "docs/ok.md" not in proc.stdout and "CHANGELOG.md" not in proc.stdout and "other/" not in proc.stdout
    assert "2 line(s), 1 path(s)" in proc.stdout


def test_outside_a_git_checkout_it_says_so(tmp_path: Path):
    proc = _check(tmp_path)
    assert proc.returncode == 2 and "not a git checkout" in proc.stderr
