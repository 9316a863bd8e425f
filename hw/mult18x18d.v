// Behavioural model of the Lattice ECP5 MULT18X18D multiplier: the subset hw/mult18x18d.py instantiates.
// Yosys ships MULT18X18D as a blackbox only, so the "ecp5" variant of the streaming core needs this model
// to run on Icarus Verilog or Verilator.
//
// Semantics (Lattice TN1267, ECP5 and ECP5-5G sysDSP Usage Guide): P = A * B, each operand read as signed
// when its SIGNEDx pin is high; the input registers (REG_INPUTA_CLK, REG_INPUTB_CLK), the pipeline
// register after the multiplier (REG_PIPELINE_CLK) and the output register (REG_OUTPUT_CLK) are each
// either off ("NONE") or clocked by CLK0, loaded when CE0 is high, cleared by RST0 (RESETMODE SYNC).
// Not modelled (elaboration stops): CLK1..CLK3, SOURCEB_MODE other than B_SHIFT, SOURCEA / SOURCEB high
// (the shift-out chains), C. GSR is ignored.

module MULT18X18D(
  input A17, A16, A15, A14, A13, A12, A11, A10, A9, A8, A7, A6, A5, A4, A3, A2, A1, A0,
  input B17, B16, B15, B14, B13, B12, B11, B10, B9, B8, B7, B6, B5, B4, B3, B2, B1, B0,
  input C17, C16, C15, C14, C13, C12, C11, C10, C9, C8, C7, C6, C5, C4, C3, C2, C1, C0,
  input SIGNEDA, SIGNEDB, SOURCEA, SOURCEB,
  input CLK0, CE0, RST0,
  output P35, P34, P33, P32, P31, P30, P29, P28, P27, P26, P25, P24, P23, P22, P21, P20, P19, P18, P17, P16, P15, P14, P13, P12, P11, P10, P9, P8, P7, P6, P5, P4, P3, P2, P1, P0
);
  parameter REG_INPUTA_CLK = "NONE";
  parameter REG_INPUTB_CLK = "NONE";
  parameter REG_PIPELINE_CLK = "NONE";
  parameter REG_OUTPUT_CLK = "NONE";
  parameter SOURCEB_MODE = "B_SHIFT";
  parameter RESETMODE = "SYNC";
  parameter GSR = "ENABLED";

  initial begin
    if ((REG_INPUTA_CLK != "NONE" && REG_INPUTA_CLK != "CLK0") || (REG_INPUTB_CLK != "NONE" && REG_INPUTB_CLK != "CLK0")
        || (REG_PIPELINE_CLK != "NONE" && REG_PIPELINE_CLK != "CLK0") || (REG_OUTPUT_CLK != "NONE" && REG_OUTPUT_CLK != "CLK0")
        || SOURCEB_MODE != "B_SHIFT" || RESETMODE != "SYNC") begin
      $display("MULT18X18D model: configuration not modelled (a clock other than CLK0, SOURCEB_MODE, RESETMODE)");
      $finish;
    end
  end

  wire [17:0] a = {A17, A16, A15, A14, A13, A12, A11, A10, A9, A8, A7, A6, A5, A4, A3, A2, A1, A0};
  wire [17:0] b = {B17, B16, B15, B14, B13, B12, B11, B10, B9, B8, B7, B6, B5, B4, B3, B2, B1, B0};
  reg [17:0] a_q = 18'h0, b_q = 18'h0;
  reg sa_q = 1'b0, sb_q = 1'b0;
  reg [35:0] pipe_q = 36'h0, out_q = 36'h0;

  wire [17:0] a_in = REG_INPUTA_CLK == "NONE" ? a : a_q;
  wire [17:0] b_in = REG_INPUTB_CLK == "NONE" ? b : b_q;
  wire sa = REG_INPUTA_CLK == "NONE" ? SIGNEDA : sa_q;
  wire sb = REG_INPUTB_CLK == "NONE" ? SIGNEDB : sb_q;
  // both operands extended to 36 bits: the low 36 bits of the product are then exact for either reading
  wire [35:0] a_ext = {{18{sa & a_in[17]}}, a_in};
  wire [35:0] b_ext = {{18{sb & b_in[17]}}, b_in};
  wire [35:0] product = a_ext * b_ext;
  wire [35:0] piped = REG_PIPELINE_CLK == "NONE" ? product : pipe_q;
  wire [35:0] p = REG_OUTPUT_CLK == "NONE" ? piped : out_q;

  always @(posedge CLK0) begin
    if (RST0) begin
      a_q <= 18'h0; b_q <= 18'h0; sa_q <= 1'b0; sb_q <= 1'b0; pipe_q <= 36'h0; out_q <= 36'h0;
    end else if (CE0) begin
      a_q <= a; b_q <= b; sa_q <= SIGNEDA; sb_q <= SIGNEDB; pipe_q <= product; out_q <= piped;
    end
  end

  assign {P35, P34, P33, P32, P31, P30, P29, P28, P27, P26, P25, P24, P23, P22, P21, P20, P19, P18, P17, P16, P15, P14, P13, P12, P11, P10, P9, P8, P7, P6, P5, P4, P3, P2, P1, P0} = p;
endmodule
