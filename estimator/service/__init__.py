"""The estimator service: DeepSEE for many devices on one edge server (docs/service.md).

A broker (:mod:`estimator.service.broker`) receives every device's feature stream, validates each message and
routes it to the worker process that holds that device's windows; workers (:mod:`estimator.service.worker`)
assemble windows by frame index, run the ONNX model on every window end (batching windows of different devices
that are ready together) and hand the estimates back to the broker, which publishes them. This is the ZeroMQ guide's
load-balancing broker, with devices rather than single requests as the unit of work, so that one device's
estimates come from one worker, in order. A worker's windows, batches and estimates are a
:class:`~estimator.service.worker_core.WorkerCore`, which the broker itself can run (``workers = 0``).
"""
