"""The harness and the processes the DDS tests start: publishers, faulty and slow nodes, a domain per test."""
