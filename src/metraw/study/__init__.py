"""What a study is made of: its parameter space (``points``, params.yaml), its source data (``sources``), the
pretrainings it needs (``pretraining``) and the real images of its sim-to-real benchmark (``sim_to_real``)."""
