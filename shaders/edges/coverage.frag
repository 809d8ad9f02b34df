// Depth only: the coverage pass writes no colour.
void main() {
}
