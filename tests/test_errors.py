"""User errors survive the trip from a worker process to the parent whole."""

import pickle

import pytest

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.evaluation.results import ResultsFormatError
from sianms_cli.processes import worker_pool


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
