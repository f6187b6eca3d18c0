"""What a study concludes: Gaussian-process tolerances (``tolerance``), the property model (``property_model``),
the aggregation of the runs' results (``aggregate``) and its figures (``figures``), the specification
(``builder``) and the runtime decision on an image (``check``)."""
