"""A fleet's recordings as one table: a hive-partitioned Parquet dataset (``export-parquet``)
and DuckDB's reports over it (``query``).

=============  ==========================================================================
module         holds
=============  ==========================================================================
``schema``     the dataset's contract: tables, columns, types, partitioning, schema version
``rows``       the one engine's windows (conformance/offline/engine.py) as the tables' rows
``table``      one table's Parquet file of one recording, written a row group at a time
``export``     a recording (MCAP, pcap, pcapng) to the dataset's files; many, in processes
``query``      DuckDB views over the dataset and the built-in reports
``html``       the reports as one HTML page with inline SVG charts
=============  ==========================================================================

pyarrow and duckdb are the ``fleet`` extra (``pip install 'fairino-conformance[fleet]'``);
without them the commands say so in one line.  The layout is documented in docs/fleet.md
("A fleet's recordings as one table") as a contract with :data:`schema.SCHEMA_VERSION`.
"""
