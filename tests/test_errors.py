"""User errors survive the trip from a worker process to the parent whole."""

import pickle

import pytest

from sianms_cli.cli._app import command
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.evaluation.results import ResultsFormatError
from sianms_cli.processes import Terminated, worker_pool


@pytest.mark.parametrize("error", [
    SianmsError("--seed must be between 0 and 2**63 - 1, got -1"),
    DataFormatError("cache/frustums/scene-0001.parquet", "not a readable Parquet file", field="x"),
    ResultsFormatError("results.json", "must be a number in [0, 1], got 1.5", token="abc", field="detection_score",
                       box_index=3),
])
def test_a_pickled_error_keeps_its_message_and_fields(error):
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error) and str(copy) == str(error) and copy.__dict__ == error.__dict__


def _fail(path: str) -> None:
    raise DataFormatError(path, "not a readable Parquet file", field="footer")


def test_an_error_raised_in_a_worker_reaches_the_parent_as_itself():
    with pytest.raises(DataFormatError, match="^shard.parquet: field 'footer': not a readable Parquet file$"):
        with worker_pool(1) as pool:
            list(pool.imap(_fail, ["shard.parquet"]))


def probe_app(failure: BaseException):
    """A one-command application whose command raises ``failure``, wrapped as every sianms command is."""
    import typer

    probe = typer.Typer()

    @command("fail", probe)
    def fail() -> None:
        raise failure

    @command("other", probe)  # a second command keeps typer from collapsing the group into its command
    def other() -> None:
        pass

    return probe


@pytest.mark.parametrize("rank", [None, "0", "1"])
def test_under_torchrun_only_rank_0_says_it_was_interrupted(monkeypatch, rank):
    from typer.testing import CliRunner

    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    result = CliRunner().invoke(probe_app(Terminated()), ["fail"])
    assert result.exit_code == 143
    said = "interrupted (SIGTERM); finished outputs are kept, a rerun resumes or starts afresh\n"
    assert result.output == ("" if rank == "1" else said)


@pytest.mark.parametrize("rank, prefix", [(None, "error: "), ("0", "error: "), ("3", "error: rank 3: ")])
def test_under_torchrun_another_ranks_error_names_its_rank(monkeypatch, rank, prefix):
    from typer.testing import CliRunner

    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    result = CliRunner().invoke(probe_app(SianmsError("--epochs: must be >= 1")), ["fail"])
    assert result.exit_code == 2 and result.output == f"{prefix}--epochs: must be >= 1\n"
