"""The sample cache: the content-addressed store, its housekeeping at the start of a job, and export of a preset's
entries to another cache folder."""
