//! imulogd: the acquisition daemon.
