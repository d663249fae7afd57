"""Every file a run writes: summary.json, GeoTIFFs, track.parquet/track.csv, PNG plots and the HTML report."""
