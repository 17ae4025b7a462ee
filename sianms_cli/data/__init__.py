"""The prepared cache: Parquet schemas, shard writers and readers, frustums, pairs and the
index the hard-negative sampler needs."""
