"""The model artefact a worker serves, readable without PyTorch: the ONNX model and its metadata, the compatibility
record that refuses a model made for other inputs, the per-camera input standardisation and the label and input
transforms. Training writes it (:mod:`estimator.deepsee.export`); the service and the app read it."""
