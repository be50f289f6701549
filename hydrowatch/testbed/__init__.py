"""A multi-host deployment on one machine, for tests and benchmarks (issue 18): hosts in network namespaces joined
by virtual links (or loopback), a throwaway PostgreSQL cluster, an MLflow tracking server process, and the services
of compose.yaml started on those hosts as clients of a router (docs/bus.md, "The router topology")."""

from hydrowatch.testbed.hosts import Host, Network, namespaces_unavailable
from hydrowatch.testbed.postgres import PostgresCluster, postgres_unavailable
from hydrowatch.testbed.tracking_server import TrackingServer

__all__ = ["Host", "Network", "PostgresCluster", "TrackingServer", "namespaces_unavailable", "postgres_unavailable"]
