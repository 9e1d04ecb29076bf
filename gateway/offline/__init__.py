"""The offline side: recordings (CSV, Parquet), the diagnosis report, figures, progress
bars. Nothing here is needed by the daemon."""
