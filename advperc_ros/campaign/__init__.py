"""Campaigns: many attacks (or replays of found attacks) from one file, run by a pool of workers,
resumable, summed up in one table (CSV/JSON, Markdown, HTML with the pictures) and a JUnit file.

spec.py reads and checks the campaign file and names its cells; execute.py runs a cell and holds the
executors (serial, process, ray); summary.py writes the summary; run.py ties them together.
"""
