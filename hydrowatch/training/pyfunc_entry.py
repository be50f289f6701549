"""The code of hydrowatch's MLflow models (MLflow's "models from code"): MLflow copies this file into each logged
model (``pyfunc_entry.py`` beside ``MLmodel``) and runs it to load the model, instead of unpickling a Python object.

Not imported by hydrowatch itself: :func:`hydrowatch.training.mlflow_model.log_bundle_model` hands MLflow its path.
"""

from mlflow.models import set_model

from hydrowatch.training.pyfunc import BundleModel

set_model(BundleModel())
