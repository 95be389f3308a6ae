"""Tools for the project's developers (the import scan); nothing here is imported by the pipeline."""
