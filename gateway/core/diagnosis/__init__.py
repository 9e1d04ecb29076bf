"""What the simulation gets wrong: compare a recording with the baseline sensor model,
name the physical cause, fit an extended model, measure the gain (`adxlgw diagnose`)."""
from gateway.core.diagnosis.context import DiagnosisInput
from gateway.core.diagnosis.selection import ALL_EFFECTS, SETUP_PROPERTIES, DiagnosisResult, diagnose, list_effects

__all__ = ["ALL_EFFECTS", "DiagnosisInput", "DiagnosisResult", "SETUP_PROPERTIES", "diagnose", "list_effects"]
