"""Campaigns: thousands of in-process flights on Dask, their results in Parquet, and the
answers drawn from them (``heli-sitl campaign``; docs/campaigns.md)."""
