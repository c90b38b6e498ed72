"""Campaigns: parameter sweeps, tolerance Monte Carlo and fleets of recorded drives (docs/campaigns.md).

* :mod:`~belt_drive_ros.campaign.spec`: the campaign file and its variants.
* :mod:`~belt_drive_ros.campaign.metrics`: the metrics of one run.
* :mod:`~belt_drive_ros.campaign.execute`: batches on a Dask cluster, results streamed to Parquet, resume.
* :mod:`~belt_drive_ros.campaign.report`: summary and pictures.
"""
