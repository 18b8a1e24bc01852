__import__("pcmm._moved", fromlist=["moved"]).moved(__name__, "pcmm.studies.sweep")  # deprecated path
