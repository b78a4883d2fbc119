"""The file family: experiment CSVs (schema, loading, writing), physical
units and their parsing, the declarations a file may carry (materials,
bodies) and output files that are never overwritten.  It knows nothing of
solves or fits.
"""
