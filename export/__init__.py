"""ONNX export, INT8 quantization and the 2-core benchmark (torch).
(Contents arrive with the export issue.)
"""
