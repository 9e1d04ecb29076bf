"""The daemon's config, turned into what each part takes: driver settings, calibration,
the estimator's settings. Pure functions of a validated `Config` (one place to read
when a config key seems to have no effect).

The estimator's, the calibration's and the board protocol's imports (numpy, numba and the
compiled code they bring, a second or more) are made in the functions that need them: the daemon builds its
board side off the event loop, after the wires listen (supervisor.Gateway.start), and
the wires' settings must not wait for them."""
from __future__ import annotations

import socket
from typing import TYPE_CHECKING

from drivers.can_frames import frame_table
from drivers.can_publisher import CanPublisherConfig
from drivers.modbus_server import ModbusServerConfig
from drivers.serial_port import SerialSettings
from drivers.sparkplug_settings import SparkplugSettings
from gateway.config import Config, read_bounded
from gateway.errors import ConfigError, InputError

if TYPE_CHECKING:
    from gateway.core.conversion import Calibration
    from gateway.core.estimator_settings import EstimatorSettings


def calibration_from(cfg: Config) -> Calibration:
    from gateway.core.conversion import AxisCalibration, Calibration  # numba (see the module's doc)

    c = cfg.calibration
    return Calibration(AxisCalibration(c.zero_g_duty_x, c.sensitivity_x),
                       AxisCalibration(c.zero_g_duty_y, c.sensitivity_y))


def modbus_config_from(cfg: Config) -> ModbusServerConfig:
    m = cfg.modbus
    return ModbusServerConfig(
        tcp_enabled=m.tcp_enabled, host=m.host, port=m.port, unit_id=m.unit_id, word_order=m.word_order,
        writes_enabled=m.writes_enabled, write_allow=tuple(m.write_allow), rtu_enabled=m.rtu_enabled,
        rtu_port=m.rtu_port, rtu_baudrate=m.rtu_baudrate, rtu_parity=m.rtu_parity,
        rtu_writes_enabled=m.rtu_writes_enabled,
        max_connections=m.max_connections, priority_clients=tuple(m.priority_clients),
        idle_timeout_s=m.idle_timeout_s, peer_log_interval_s=m.peer_log_interval_s, device_name=m.device_name,
    )


def can_config_from(cfg: Config) -> CanPublisherConfig | None:
    """The CAN publisher's settings; None when [can] is off."""
    c = cfg.can
    if not c.enabled:
        return None
    return CanPublisherConfig(
        interface=c.interface, channel=c.channel,
        bitrate=None if c.interface == "socketcan" else c.bitrate,
        period_ms=float(c.period_ms),
        sync_to_updates=c.sync_to_updates,
        min_interval_ms=None if c.min_interval_ms < 0 else float(c.min_interval_ms),
        commands_enabled=c.commands_enabled,
        frames=frame_table(c.base_id),
    )


def mqtt_settings_from(cfg: Config) -> SparkplugSettings | None:
    """The Sparkplug B edge node's settings; None when [mqtt] is off. Reads the
    credentials file (ConfigError naming it when it cannot be read or has no user)."""
    m = cfg.mqtt
    if not m.enabled:
        return None
    username = password = None
    if m.credentials_file:
        username, password = read_credentials(m.credentials_file,
                                              f"{cfg.source}: mqtt.credentials_file {m.credentials_file}")
    return SparkplugSettings(
        host=m.host, port=m.port, group_id=m.group_id, edge_node_id=m.edge_node_id or socket.gethostname(),
        device_id=m.device_id, qos=m.qos, rate_hz=m.rate_hz, keepalive_s=m.keepalive_s,
        username=username, password=password, tls_ca_file=m.tls_ca_file or None,
        commands_enabled=m.commands_enabled, primary_host_id=m.primary_host_id or None,
    )


MAX_CREDENTIALS_BYTES = 4096  # one line of user:password; anything bigger is not that file


def read_credentials(path: str, where: str) -> tuple[str, str]:
    """(username, password) from the first line, username:password, of `path`; ConfigError
    starting with `where` when it cannot be read or is not that."""
    raw = read_bounded(path, MAX_CREDENTIALS_BYTES, where, "credentials file")
    try:
        first = raw.decode("utf-8").splitlines()[0] if raw.strip() else ""
    except UnicodeDecodeError as err:
        raise ConfigError(f"{where}: not UTF-8") from err
    username, sep, password = first.partition(":")
    if not sep or not username:
        raise ConfigError(f"{where}: the first line must be username:password")
    return username, password


def batch_frames_for(cfg: Config) -> int:
    """How many SAMPLE frames wake the gateway: serial.batch_frames, but 1 when CAN
    sends a frame pair per sample (mixed mode), which needs a wakeup per sample."""
    return 1 if cfg.can.enabled and cfg.can.min_interval_ms >= 0 else cfg.serial.batch_frames


def serial_settings_from(cfg: Config, port: str) -> SerialSettings:
    from drivers.board_protocol import SAMPLE_FRAME_LENGTH  # numpy (see the module's doc)

    s = cfg.serial
    return SerialSettings(port=port, baudrate=s.baudrate, reconnect_initial_s=s.reconnect_min_s,
                          reconnect_max_s=s.reconnect_max_s,
                          wake_min_bytes=batch_frames_for(cfg) * SAMPLE_FRAME_LENGTH)


def load_sample_path_model(path: str):
    """The extended sensor model at `path`, checked for the sample path: InputError
    naming the file when it cannot be read, is not a model, has an unknown term, one
    outside its physical range, or one the sample path cannot apply as samples arrive."""
    from gateway.core.model_compensation import sample_path_refusal  # numpy (see the module's doc)
    from gateway.sensor_model_file import load_sensor_model

    model = load_sensor_model(path)
    refusal = sample_path_refusal(model, path)
    if refusal:
        raise InputError(refusal)
    return model


def sensor_model_from(cfg: Config):
    """The model calibration.model names (None: none); ConfigError naming the config,
    the key and the file."""
    if not cfg.calibration.model:
        return None
    try:
        return load_sample_path_model(cfg.calibration.model)
    except InputError as err:
        raise ConfigError(f"{cfg.source}: calibration.model: {err}") from err


def model_terms_from(cfg: Config):
    """The per-sample correction rows of calibration.model (model_compensation.sample_terms)."""
    from gateway.core.model_compensation import sample_terms
    from gateway.daemon.sample_pipeline import NO_MODEL_TERMS

    model = sensor_model_from(cfg)
    return NO_MODEL_TERMS if model is None else sample_terms(model)


def estimator_settings_from(cfg: Config) -> EstimatorSettings:
    """The estimator's settings from the sensor model, with the fitted drift model if one is configured."""
    from gateway.core.estimator_settings import from_sensor_model  # numba (see the module's doc)
    from gateway.core.sensor_model import SensorParams
    from gateway.drift_model_file import load_drift_model

    drift = None
    if cfg.estimator.drift_model:
        try:
            drift = load_drift_model(cfg.estimator.drift_model)
        except InputError as err:
            raise ConfigError(f"{cfg.source}: estimator.drift_model: {err}") from err
    settings = from_sensor_model(SensorParams(), drift_fit=drift, axis=cfg.calibration.axis)
    model = sensor_model_from(cfg)
    if model is not None:  # the board's raw counts: the nominal part's pole is the reference
        from gateway.core.model_compensation import settings_with_model_lag

        settings = settings_with_model_lag(settings, model, SensorParams().bandwidth_hz)
    return settings
