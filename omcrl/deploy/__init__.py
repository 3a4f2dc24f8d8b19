"""Deployment (paper VI-B): ONNX export, an onnxruntime policy, the drone control loop with its safety rules, a
simulated drone, the DJI Tello through djitellopy, motion capture, and a loopback fake Tello for tests."""

from omcrl.deploy.check import parity, record_observations
from omcrl.deploy.export import ExportError, export_onnx
from omcrl.deploy.loop import ControlLoop, FlightResult, Safety
from omcrl.deploy.runtime import ModelSpecError, OnnxPolicy
from omcrl.deploy.sim import SimulatedDrone

__all__ = [
    "ControlLoop",
    "ExportError",
    "FlightResult",
    "ModelSpecError",
    "OnnxPolicy",
    "Safety",
    "SimulatedDrone",
    "export_onnx",
    "parity",
    "record_observations",
]
